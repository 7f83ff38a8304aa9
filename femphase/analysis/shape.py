"""Per-particle shape observables: centroid, area, shape tensor, elongation, orientation.

Conventions:

* shape tensor R_i = −∫ ∇φ_i ∇φ_iᵀ (the paper's sign). Its eigenvector with the largest
  eigenvalue (the least negative) lies along the particle's elongation. On the structured
  channel it is computed from nodal central differences with the nodal quadrature
  (:func:`grid_moments`): that rule has the square symmetry of the lattice, so a
  centred disc has exactly zero elongation. The exact integral of the P1 gradients
  (:func:`shape_tensors`, any mesh) inherits the bias of the triangulation's diagonals: a
  disc of R = 8 at h = 1 shows r ≈ 0.026 along the diagonal. Both converge as O(h²);
* elongation r = λ1/λ2 − 1 ≥ 0 with |λ1| ≥ |λ2| the eigenvalues of R (an aspect ratio
  minus one; 0 for a disc);
* orientation θ ∈ (−π/2, π/2]: the angle of the elongation axis from the x axis (nematic);
* centroid: φ-weighted mean, the x coordinate as a circular mean over the period Lx, so a
  particle straddling the periodic seam has its centroid on the right side;
* area: ∫φ² (the quantity the soft area constraint holds at πR²).

Integrals are exact for P1 fields (gradients are constant per element); the potential-type
integrals use the nodal (lumped) quadrature of :mod:`femphase.energy`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..discretisation import P1Operators
from ..state import State
from ..windows import pad_window


@dataclass(frozen=True)
class ShapeObservables:
    """Arrays of length N: centroid x and y, area ∫φ², elongation r, orientation θ."""

    x: np.ndarray
    y: np.ndarray
    area: np.ndarray
    elongation: np.ndarray
    orientation: np.ndarray


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


def grid_moments(state: State, lumped_mass: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Area ∫φ² (N,), centroids (N, 2) and shape tensors (N, 2, 2) of the fields on the
    structured channel, with the nodal quadrature.

    Shape tensor: R_i = −Σ_k m_k ∇_h φ_ik ∇_h φ_ikᵀ with central differences ∇_h, the field
    mirrored at the walls (∂yφ = 0) and zero beyond a window's edge. Centroid: φ-weighted,
    x as a circular mean over the period, in [0, Lx).
    """
    grid = state.grid
    n = state.n_particles
    area, centre, tensors = np.empty(n), np.empty((n, 2)), np.empty((n, 2, 2))
    groups: dict[tuple, list[int]] = {}
    for i, w in enumerate(state.windows):
        groups.setdefault(w.key(grid, alternating=False), []).append(i)
    # windows of one key have the same shape, walls and lumped-mass rows: one batch each
    for members in groups.values():
        windows = [state.windows[i] for i in members]
        w = windows[0]
        phi = np.stack([state.fields[i] for i in members])  # (k, ny, nx)
        m = lumped_mass[w.node_indices(grid)].reshape(w.ny, w.nx)
        weighted = phi * m
        area[members] = np.einsum("kij,kij->k", weighted, phi)
        total = weighted.sum(axis=(1, 2))
        angle = 2 * np.pi * grid.h * np.stack([v.columns(grid) for v in windows]) / grid.length  # (k, nx)
        column_weight = weighted.sum(axis=1)
        cos = np.einsum("kj,kj->k", column_weight, np.cos(angle))
        sin = np.einsum("kj,kj->k", column_weight, np.sin(angle))
        centre[members, 0] = (np.arctan2(sin, cos) % (2 * np.pi)) * grid.length / (2 * np.pi)
        rows = grid.h * np.stack([v.rows() for v in windows])  # (k, ny)
        centre[members, 1] = np.einsum("ki,ki->k", weighted.sum(axis=2), rows) / total
        padded = pad_window(phi, w, grid, 1)
        dx = (padded[:, 1:-1, 2:] - padded[:, 1:-1, :-2]) / (2 * grid.h)
        dy = (padded[:, 2:, 1:-1] - padded[:, :-2, 1:-1]) / (2 * grid.h)
        xx, yy, xy = (-np.einsum("kij,ij,kij->k", a, m, b) for a, b in ((dx, dx), (dy, dy), (dx, dy)))
        tensors[members] = np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)
    return area, centre, tensors


def elongation_and_orientation(tensors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """r = λ1/λ2 − 1 and θ ∈ (−π/2, π/2] of the elongation axis, from tensors (N, 2, 2)."""
    values, vectors = np.linalg.eigh(tensors)  # ascending: values[:, 1] is the least negative
    with np.errstate(divide="ignore", invalid="ignore"):
        elongation = values[:, 0] / values[:, 1] - 1.0
    axis = vectors[:, :, 1]
    orientation = np.arctan2(axis[:, 1], axis[:, 0])
    orientation = np.where(orientation <= -np.pi / 2, orientation + np.pi, orientation)
    orientation = np.where(orientation > np.pi / 2, orientation - np.pi, orientation)
    return elongation, orientation


def shape_observables(state: State, ops: P1Operators) -> ShapeObservables:
    """All per-particle shape observables of a state on the structured channel."""
    area, centre, tensors = grid_moments(state, ops.lumped_mass)
    elongation, orientation = elongation_and_orientation(tensors)
    return ShapeObservables(centre[:, 0], centre[:, 1], area, elongation, orientation)
