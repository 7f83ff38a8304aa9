"""Per-particle shape observables: centroid, area, shape tensor, elongation, orientation.

Conventions:

* shape tensor R_i = −∫ ∇φ_i ∇φ_iᵀ (the paper's sign). Its eigenvector with the largest
  eigenvalue (the least negative) lies along the particle's elongation. On the structured
  channel it is computed from nodal central differences with the nodal quadrature
  (:func:`shape_tensors_grid`): that rule has the square symmetry of the lattice, so a
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
from ..mesh import ChannelGrid
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


def fields_matrix(state: State) -> sp.csc_matrix:
    """All fields as one sparse (n_nodes, N) matrix: column i is φ_i on the whole mesh."""
    rows = np.concatenate([w.node_indices(state.grid) for w in state.windows])
    cols = np.repeat(np.arange(state.n_particles), [f.size for f in state.fields])
    values = np.concatenate([f.ravel() for f in state.fields])
    return sp.csc_matrix((values, (rows, cols)), shape=(state.grid.n_nodes, state.n_particles))


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


def shape_tensors_grid(state: State, lumped_mass: np.ndarray) -> np.ndarray:
    """R_i = −Σ_k m_k ∇_h φ_ik ∇_h φ_ikᵀ with central differences ∇_h → (N, 2, 2).

    The field is mirrored at the walls (∂yφ = 0) and zero beyond a window's edge.
    """
    grid = state.grid
    out = np.empty((state.n_particles, 2, 2))
    for i, (phi, w) in enumerate(zip(state.fields, state.windows)):
        padded = pad_window(phi, w, grid, 1)
        dx = (padded[1:-1, 2:] - padded[1:-1, :-2]) / (2 * grid.h)
        dy = (padded[2:, 1:-1] - padded[:-2, 1:-1]) / (2 * grid.h)
        m = lumped_mass[w.node_indices(grid)].reshape(w.ny, w.nx)
        xy = -np.sum(m * dx * dy)
        out[i] = [[-np.sum(m * dx * dx), xy], [xy, -np.sum(m * dy * dy)]]
    return out


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


def centroids(fields: sp.spmatrix | np.ndarray, grid: ChannelGrid, lumped_mass: np.ndarray) -> np.ndarray:
    """φ-weighted centroids (N, 2); x is a circular mean over the period, in [0, Lx)."""
    x, y = grid.coordinates()
    node_x = np.tile(x, grid.ny)
    node_y = np.repeat(y, grid.nx)
    angle = 2 * np.pi * node_x / grid.length
    weights = sp.diags(lumped_mass) @ fields
    total = np.asarray(weights.sum(axis=0)).ravel()
    cos = np.asarray(weights.T @ np.cos(angle)).ravel()
    sin = np.asarray(weights.T @ np.sin(angle)).ravel()
    cx = (np.arctan2(sin, cos) % (2 * np.pi)) * grid.length / (2 * np.pi)
    cy = np.asarray(weights.T @ node_y).ravel() / total
    return np.stack([cx, cy], axis=1)


def shape_observables(state: State, ops: P1Operators) -> ShapeObservables:
    """All per-particle shape observables of a state."""
    fields = fields_matrix(state)
    centre = centroids(fields, state.grid, ops.lumped_mass)
    area = np.asarray(fields.multiply(fields).T @ ops.lumped_mass).ravel()
    elongation, orientation = elongation_and_orientation(shape_tensors_grid(state, ops.lumped_mass))
    return ShapeObservables(centre[:, 0], centre[:, 1], area, elongation, orientation)
