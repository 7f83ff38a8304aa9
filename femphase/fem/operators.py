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
    """

    mass: sp.csr_matrix
    stiffness: sp.csr_matrix
    lumped_mass: np.ndarray
    gradient: tuple[sp.csr_matrix, sp.csr_matrix]
    element_area: np.ndarray


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
    gradient = tuple(
        sp.csr_matrix((grads[:, axis].ravel(), (rows, cols)), shape=(n_elements, n_dofs))
        for axis in (0, 1)
    )
    return P1Operators(
        mass=mass,
        stiffness=stiffness,
        lumped_mass=np.asarray(mass.sum(axis=1)).ravel(),
        gradient=gradient,
        element_area=areas,
    )


def shape_tensors(fields: sp.spmatrix | np.ndarray, ops: P1Operators) -> np.ndarray:
    """R_i = −∫∇φ_i∇φ_iᵀ for fields (n_nodes, N) → (N, 2, 2)."""
    gx = ops.gradient[0] @ fields
    gy = ops.gradient[1] @ fields
    area = ops.element_area

    def integral(a, b):
        product = a.multiply(b) if sp.issparse(a) else a * b
        return -np.asarray(area @ product).ravel()

    xx, yy, xy = integral(gx, gx), integral(gy, gy), integral(gx, gy)
    return np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
