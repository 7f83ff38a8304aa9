"""Per-particle shape observables: centroid, area, shape tensor, elongation, orientation.

Conventions:

* shape tensor R_i = −∫ ∇φ_i ∇φ_iᵀ (the paper's sign). Its eigenvector with the largest
  eigenvalue (the least negative) lies along the particle's elongation. On the structured
  channel it is computed from nodal central differences with the nodal quadrature
  (:meth:`femphase.channel.ChannelDomain.shape_moments`): that rule has the square symmetry of the lattice, so a
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
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from ..discretisation import P1Operators

if TYPE_CHECKING:
    from ..state import State


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


def shape_observables(state: "State") -> ShapeObservables:
    """All per-particle shape observables of a state (the domain's rule for the moments:
    :meth:`femphase.domain.Domain.shape_moments`)."""
    layout, phi = state.flat()
    area, centre, tensors = state.domain.shape_moments(layout, phi)
    elongation, orientation = elongation_and_orientation(tensors)
    return ShapeObservables(centre[:, 0], centre[:, 1], area, elongation, orientation)
