"""Semi-Lagrangian advection on meshes, for fast steady flows.

Over a step dt every dof takes the value the field had at its departure point x, where the
fluid at the dof was dt earlier: x by classical RK4 on the flow's nodal velocity (P1
interpolated, steps of at most :data:`DEPARTURE_STEP` median edge), and φ(x) from the P1
interpolant plus a curvature correction on the triangle (corners a, b, c; barycentric λ)
that holds x,

    φ(x) ≈ Σ_a λ_a φ_a − ½ Σ_{a<b} λ_a λ_b e_abᵀ H e_ab,   e_ab = x_a − x_b,

exact for quadratics, with H the Hessian of a least-squares quadratic over the first ring of
the triangle's corners (about 12 entries per row). The correction vanishes at the nodes: a
fluid at rest moves nothing. A steady flow's step over dt is one sparse matrix, built once
and applied to all windows as one block-diagonal product.

Why only for fast flows (:data:`COURANT`): the interpolation error is made at every step, so
it grows as the Courant number u dt/h falls; the Galerkin step's does not depend on dt. A
disc translating at u = 1 on a Delaunay mesh at h = 1 (default scheme) moved with −0.17 %
and stretched by +0.005 under the Galerkin step at every dt; under this step by +0.05 %,
−0.003 to −0.006 at Courant numbers 0.9–1.9, but +0.15 %, +0.012 at 0.5–0.9 and +0.67 %,
+0.045 at 0.02–0.23 (docs/decisions/0042-mesh-semi-lagrangian-not-kept.md); at u = 3
(Courant numbers 2.8–5.6) by +0.03 %, −0.004 against −0.07 %, +0.010
(verification/mesh_advection.py). Where the Galerkin step subcycles (ω dt > 1), its cost
grows with u while this step's does not.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from femphase.domains.base import Domain
from femphase.domains.layout import Layout
from femphase.domains.mesh.advection import GalerkinAdvection
from femphase.domains.mesh.location import barycentric, centroid_tree, locate
from femphase.fem.blocks import BlockPattern
from femphase.flows import Flow

__all__ = ["COURANT", "DEPARTURE_STEP", "SemiLagrangian", "courant_number", "departure_points",
           "interpolation_matrix"]

#: The Courant number max|v| dt / (median edge) from which a steady flow on a mesh advects
#: semi-Lagrangian instead of by the Galerkin step (module docstring).
COURANT = 2.0
#: The largest RK4 step of the departure points, in median edges: on the velocity's P1
#: interpolant, steps of one edge put the points within 4e-6 edges of steps of a tenth
#: (examples/straight_mesh.toml at Courant number 3.1), in 0.13× the time.
DEPARTURE_STEP = 1.0
#: Elements fitted at once by :func:`interpolation_matrix`.
FIT_PART = 4096


def courant_number(domain: Domain, velocity: np.ndarray, dt: float) -> float:
    """max|v| dt / (median edge) for the (2, n_dofs) nodal ``velocity``."""
    return float(np.max(np.hypot(*velocity))) * dt / domain.median_edge


def _unwrap(domain: Domain, x: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """x moved by whole periods to lie within half a period of ``centre``."""
    half = 0.5 * domain.period
    return centre + np.mod(x - centre + half, domain.period) - half


def _containing(domain: Domain, points: np.ndarray, tree) -> tuple[np.ndarray, np.ndarray]:
    """(elements, λ (3, n)) for points (2, n) with x in
    the period; ``tree`` the mesh's :func:`~femphase.domains.mesh.location.centroid_tree`. A
    point outside every triangle (beyond a wall or into an obstacle, by the departure's
    integration error) takes the nearest node's triangle, its λ clipped to it."""
    mesh = domain.mesh
    elements = locate(mesh, points, tree=tree)
    lost = np.flatnonzero(elements < 0)
    if lost.size:  # on the seam, the other side's image; else the nearest node's triangle
        image = points[:, lost].copy()
        image[0] += np.where(image[0] < domain.x0 + 0.5 * domain.period, domain.period, -domain.period)
        elements[lost] = locate(mesh, image, tree=tree)
        still = lost[elements[lost] < 0]
        if still.size:
            elements[still] = _element_of_node(mesh)[_nearest_nodes(mesh, points[:, still])]
    corners = mesh.p[:, mesh.t[:, elements]]  # (2, 3, n)
    inside = points.copy()
    inside[0] = _unwrap(domain, points[0], corners[0].mean(axis=0))
    s, t = barycentric(corners[:, 0], corners[:, 1], corners[:, 2], inside)
    weights = np.clip(np.stack([1.0 - s - t, s, t]), 0.0, None)
    return elements, weights / weights.sum(axis=0)


def _nearest_nodes(mesh, points: np.ndarray) -> np.ndarray:
    return cKDTree(mesh.p.T).query(points.T)[1]


def _element_of_node(mesh) -> np.ndarray:
    """One triangle of every node."""
    out = np.empty(mesh.p.shape[1], dtype=np.int64)
    out[mesh.t.ravel()] = np.tile(np.arange(mesh.t.shape[1]), 3)
    return out


def _p1_at(domain: Domain, values: np.ndarray, points: np.ndarray, tree) -> np.ndarray:
    """(…, n): the P1 interpolant of dof ``values`` (…, n_dofs) at points (2, n)."""
    elements, weights = _containing(domain, points, tree)
    corner_dofs = domain.dof_map[domain.mesh.t[:, elements]]  # (3, n)
    return np.einsum("...kn,kn->...n", values[..., corner_dofs], weights)


def departure_points(domain: Domain, velocity: np.ndarray, dt: float) -> np.ndarray:
    """(2, n_dofs): where the fluid at each dof was dt earlier in the steady nodal
    ``velocity`` (2, n_dofs), x wrapped into the period (module docstring)."""
    steps = max(1, int(np.ceil(courant_number(domain, velocity, dt) / DEPARTURE_STEP)))
    h = -dt / steps
    low, high = domain.y_range
    x = np.array(domain.coordinates, dtype=float)
    tree = centroid_tree(domain.mesh)

    def rate(at: np.ndarray) -> np.ndarray:
        inside = np.stack([domain.x0 + np.mod(at[0] - domain.x0, domain.period), np.clip(at[1], low, high)])
        return _p1_at(domain, velocity, inside, tree)

    for _ in range(steps):
        k1 = rate(x)
        k2 = rate(x + 0.5 * h * k1)
        k3 = rate(x + 0.5 * h * k2)
        k4 = rate(x + h * k3)
        x = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return np.stack([domain.x0 + np.mod(x[0] - domain.x0, domain.period), np.clip(x[1], low, high)])


def _patches(domain: Domain, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(patch dofs (m, w), valid (m, w)): the first ring of each element's corners, the
    mass matrix's rows of its three corner dofs side by side, padded; a dof met twice is
    kept once."""
    pattern = domain.operators.mass.tocsr()
    lengths = np.diff(pattern.indptr)
    width = int(lengths.max())
    rows = np.full((domain.n_dofs, width), -1, dtype=np.int64)
    row_of_entry = np.repeat(np.arange(domain.n_dofs), lengths)
    rows[row_of_entry, np.arange(pattern.nnz) - pattern.indptr[row_of_entry]] = pattern.indices
    corner_rows = rows[domain.dof_map[domain.mesh.t[:, elements]]]  # (3, m, width)
    patch = np.sort(corner_rows.transpose(1, 0, 2).reshape(elements.size, -1), axis=1)
    valid = patch >= 0
    valid[:, 1:] &= patch[:, 1:] != patch[:, :-1]
    return np.where(valid, patch, 0), valid


def _curvature_fits(domain: Domain, elements: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(patch dofs (m, w), c (m, 3, w)): per element, the rows of its least-squares
    quadratic's coefficients of x², xy, y² (coordinates about the element's centroid in median
    edges) in the patch values; padding and repeats have zero columns."""
    mesh, edge = domain.mesh, domain.median_edge
    patch, valid = _patches(domain, elements)
    centre = mesh.p[:, mesh.t[:, elements]].mean(axis=1)  # (2, m)
    xd, yd = domain.coordinates
    dx = (_unwrap(domain, xd[patch], centre[0][:, None]) - centre[0][:, None]) / edge
    dy = (yd[patch] - centre[1][:, None]) / edge
    basis = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=2) * valid[..., None]
    return patch, np.linalg.pinv(basis)[:, 3:, :]


def interpolation_matrix(domain: Domain, points: np.ndarray) -> sp.csr_matrix:
    """(n, n_dofs): the quadratic-exact interpolant (module docstring) at ``points`` (2, n),
    x in the period; canonical CSR."""
    mesh, edge = domain.mesh, domain.median_edge
    elements, weights = _containing(domain, points, centroid_tree(mesh))
    n = points.shape[1]
    unique, which = np.unique(elements, return_inverse=True)
    # in parts: the fits' least-squares systems take ~1 kB per element in their temporaries
    parts = [_curvature_fits(domain, unique[i:i + FIT_PART]) for i in range(0, unique.size, FIT_PART)]
    width = max(part[0].shape[1] for part in parts)
    patch = np.concatenate([np.pad(p, ((0, 0), (0, width - p.shape[1]))) for p, _ in parts])
    c = np.concatenate([np.pad(q, ((0, 0), (0, 0), (0, width - q.shape[2]))) for _, q in parts])
    corners = mesh.p[:, mesh.t[:, elements]] / edge  # (2, 3, n)
    correction = np.zeros((n, patch.shape[1]))
    for a, b in ((0, 1), (0, 2), (1, 2)):
        ex, ey = corners[0, a] - corners[0, b], corners[1, a] - corners[1, b]
        # e^T H e with H = [[2c_xx, c_xy], [c_xy, 2c_yy]]
        form = 2.0 * ex[:, None] ** 2 * c[which, 0] + 2.0 * (ex * ey)[:, None] * c[which, 1] \
            + 2.0 * ey[:, None] ** 2 * c[which, 2]
        correction += (weights[a] * weights[b])[:, None] * form
    rows = np.concatenate([np.repeat(np.arange(n), 3), np.repeat(np.arange(n), patch.shape[1])])
    cols = np.concatenate([domain.dof_map[mesh.t[:, elements]].T.ravel(), patch[which].ravel()])
    data = np.concatenate([weights.T.ravel(), -0.5 * correction.ravel()])
    matrix = sp.csr_matrix((data, (rows, cols)), shape=(n, domain.n_dofs))
    matrix.sum_duplicates()
    matrix.eliminate_zeros()
    return matrix


class SemiLagrangian(GalerkinAdvection):
    """The semi-Lagrangian step over dt in a steady flow (module docstring): its matrix is
    the flow's and the dt's, kept in the domain's budget; per layout, the windows' principal
    submatrices as one block-diagonal matrix (:class:`~femphase.fem.blocks.BlockPattern`)."""

    def __init__(self, domain: Domain, flow: Flow, dt: float) -> None:
        if not flow.steady:
            raise ValueError("semi-Lagrangian advection on meshes needs a steady flow (one matrix per dt)")
        super().__init__(domain, flow, dt)

    @property
    def matrix(self) -> sp.csr_matrix:
        """The step's matrix on the whole mesh (periodic dofs)."""
        return self._per_flow(f"semi-Lagrangian {self.dt!r}", lambda: interpolation_matrix(
            self.domain, departure_points(self.domain, self.velocity(0.0), self.dt)))

    def advect(self, phi: np.ndarray, layout: Layout, time: float) -> tuple[np.ndarray, Layout]:
        matrix = self.matrix
        dtype = np.dtype(phi.dtype).type
        block = self.domain.per_layout(layout, ("semi-Lagrangian", self.dt, dtype), lambda: BlockPattern(
            matrix, layout.node_index, layout.offsets).block(matrix.data.astype(dtype)), tag=matrix)
        return block @ phi, layout
