"""P1 finite-element operators on the periodic channel, in grid order.

Matrices are assembled by scikit-fem on the non-periodic mesh and folded onto the periodic
dofs: with P the n_nodes × n_dofs 0/1 matrix that sends every node to its dof,
A_periodic = Pᵀ A P. Folding is exact for P1 (the seam's basis functions are summed).

Also the exact P1 integrals the shape observables use (:func:`shape_tensors`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from skfem import Basis, BilinearForm, ElementTriP1, MeshTri
from skfem.helpers import dot, grad

__all__ = ["P1Operators", "assemble_operators", "element_gradients", "line_operators", "mass_form",
           "nodes_to_dofs", "shape_tensors", "stiffness_form"]


@BilinearForm
def mass_form(u, v, w):
    return u * v


@BilinearForm
def stiffness_form(u, v, w):
    return dot(grad(u), grad(v))


@dataclass(frozen=True)
class P1Operators:
    """Assembled operators on the periodic dofs (all n_dofs × n_dofs unless stated).

    mass              consistent mass matrix M_ij = ∫ φ_i φ_j
    stiffness         K_ij = ∫ ∇φ_i · ∇φ_j
    lumped_mass       (n_dofs,) row sums of M: the nodal quadrature weights (area per node)
    gradient          (2, n_elements, n_dofs) sparse pair: ∂x and ∂y of a P1 field per element
    element_area      (n_elements,)
    dof_gradients     the gradient by dof (CSC): indptr, elements around each dof, ∂x and ∂y
    """

    mass: sp.csr_matrix
    stiffness: sp.csr_matrix
    lumped_mass: np.ndarray
    gradient: tuple[sp.csr_matrix, sp.csr_matrix]
    element_area: np.ndarray
    dof_gradients: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


@lru_cache(maxsize=8)
def line_operators(n_nodes: int, h: float, periodic: bool) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Lumped mass (diagonal) and stiffness of P1 on a line of ``n_nodes`` nodes, spacing h:
    periodic (node n_nodes is node 0), or bounded with natural (Neumann) ends. Cached (every
    new window shape asks for them): do not modify the matrices returned.

    On the structured channel mesh with one diagonal direction, the 2D lumped mass and
    stiffness are the tensor products M_L = My⊗Mx and K = Ky⊗Mx + My⊗Kx of these (the
    diagonal edges carry no stiffness in right-angled triangles): the basis of
    :class:`femphase.fem.solvers.TensorSolver`.
    """
    weights = np.full(n_nodes, float(h))
    ends = np.zeros(n_nodes)
    if not periodic:
        weights[[0, -1]] *= 0.5
        ends[[0, -1]] = 1.0  # a bounded end node has one neighbour, not two
    off = np.ones(n_nodes - 1) / h
    stiffness = sp.diags([-off, (2.0 - ends) / h, -off], [-1, 0, 1], format="lil")
    if periodic:
        stiffness[0, n_nodes - 1] -= 1.0 / h
        stiffness[n_nodes - 1, 0] -= 1.0 / h
    return sp.diags(weights, format="csr"), stiffness.tocsr()


def nodes_to_dofs(dof_map: np.ndarray, n_dofs: int) -> sp.csr_matrix:
    """P with P[node, dof_map[node]] = 1."""
    n_nodes = dof_map.size
    return sp.csr_matrix((np.ones(n_nodes), (np.arange(n_nodes), dof_map)), shape=(n_nodes, n_dofs))


def element_gradients(mesh: MeshTri) -> tuple[np.ndarray, np.ndarray]:
    """Constant gradients of the three P1 hat functions on every element, and element areas.

    Returns grads (3, 2, n_elements) and areas (n_elements,).
    """
    p = mesh.p[:, mesh.t]  # (2, 3, n_elements)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[0] * e2[1] - e1[1] * e2[0]
    # rows of the inverse Jacobian are the gradients of the barycentric coordinates 1 and 2
    g1 = np.stack([e2[1], -e2[0]]) / det
    g2 = np.stack([-e1[1], e1[0]]) / det
    return np.stack([-g1 - g2, g1, g2]), 0.5 * np.abs(det)


def assemble_operators(mesh: MeshTri, dof_map: np.ndarray, n_dofs: int) -> P1Operators:
    """Mass, stiffness, lumped mass and element gradients of P1 on ``mesh``, folded by dof_map."""
    basis = Basis(mesh, ElementTriP1())
    fold = nodes_to_dofs(dof_map, n_dofs)
    mass = (fold.T @ mass_form.assemble(basis) @ fold).tocsr()
    stiffness = (fold.T @ stiffness_form.assemble(basis) @ fold).tocsr()
    grads, areas = element_gradients(mesh)
    n_elements = mesh.t.shape[1]
    rows = np.tile(np.arange(n_elements), 3)
    cols = dof_map[mesh.t].ravel()
    # both components in one complex matrix, so that they share one pattern (explicit zeros kept)
    both = sp.csr_matrix((grads[:, 0].ravel() + 1j * grads[:, 1].ravel(), (rows, cols)), shape=(n_elements, n_dofs))
    by_dof = both.tocsc()
    by_dof.sort_indices()
    return P1Operators(
        mass=mass,
        stiffness=stiffness,
        lumped_mass=np.asarray(mass.sum(axis=1)).ravel(),
        gradient=(sp.csr_matrix(both.real), sp.csr_matrix(both.imag)),
        element_area=areas,
        dof_gradients=(by_dof.indptr.astype(np.int64), by_dof.indices.astype(np.int64),
                       np.ascontiguousarray(by_dof.data.real), np.ascontiguousarray(by_dof.data.imag)),
    )


def shape_tensors(ops: P1Operators, node_index: np.ndarray, offsets: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """R_w = −∫∇φ_w∇φ_wᵀ, the exact P1 integral, of every window's field → (windows, 2, 2),
    in window order: window w holds positions ``offsets[w]:offsets[w + 1]``, position p the
    value ``phi[p]`` at the dof ``node_index[p]`` (zero elsewhere). One compiled pass over
    the positions and the elements around each (:func:`femphase.fem.kernels.window_gradient_moments`);
    as sparse products over all fields at once it took 19 ms a frame on
    examples/obstacle_mesh.toml (N = 95), 3 % of a run's CPU at its frame interval of 80."""
    from femphase.fem import kernels  # numba loads only where shapes are measured on a mesh

    indptr, elements, gx, gy = ops.dof_gradients
    slot = np.full(ops.element_area.size, -1, dtype=np.int64)
    moments = kernels.window_gradient_moments(indptr, elements, gx, gy, ops.element_area,
                                              np.asarray(node_index, dtype=np.int64),
                                              np.asarray(offsets, dtype=np.int64), phi, slot)
    xx, yy, xy = -moments[:, 0], -moments[:, 1], -moments[:, 2]
    return np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
