"""Shape observables on a meshed channel (the conventions of :mod:`femphase.analysis.shape`).

* shape tensor R_i = −∫∇φ_i∇φ_iᵀ: the exact integral of the P1 element gradients
  (:func:`femphase.analysis.shape.shape_tensors`, which works on any mesh through the
  domain's :class:`~femphase.discretisation.P1Operators`). On an irregular mesh its bias is
  O(h²) and varies with position (no lattice direction is preferred on average); the
  structured mesh's nodal central-difference rule has no unstructured counterpart;
* centroid: φ-weighted, x as a circular mean over the period (in [x0, x0 + period));
* area: ∫φ² with the nodal quadrature.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..analysis.shape import ShapeObservables, elongation_and_orientation, shape_tensors
from .state import MeshState


def mesh_fields_matrix(state: MeshState) -> sp.csc_matrix:
    """All fields as one sparse (n_dofs, N) matrix: column i is φ_i on the whole domain."""
    rows = np.concatenate(state.nodes)
    cols = np.repeat(np.arange(state.n_particles), [n.size for n in state.nodes])
    values = np.concatenate(state.fields)
    return sp.csc_matrix((values, (rows, cols)), shape=(state.domain.n_dofs, state.n_particles))


def mesh_centroids(fields: sp.spmatrix, state: MeshState) -> np.ndarray:
    """φ-weighted centroids (N, 2); x a circular mean over the period, in [x0, x0 + period)."""
    domain = state.domain
    x, y = domain.coordinates
    angle = 2 * np.pi * (x - domain.x0) / domain.period
    weights = sp.diags(domain.operators.lumped_mass) @ fields
    total = np.asarray(weights.sum(axis=0)).ravel()
    cos = np.asarray(weights.T @ np.cos(angle)).ravel()
    sin = np.asarray(weights.T @ np.sin(angle)).ravel()
    cx = domain.x0 + (np.arctan2(sin, cos) % (2 * np.pi)) * domain.period / (2 * np.pi)
    cy = np.asarray(weights.T @ y).ravel() / total
    return np.stack([cx, cy], axis=1)


def mesh_shape_observables(state: MeshState) -> ShapeObservables:
    """All per-particle shape observables of a state on a meshed channel."""
    ops = state.domain.operators
    fields = mesh_fields_matrix(state)
    centre = mesh_centroids(fields, state)
    area = np.asarray(fields.multiply(fields).T @ ops.lumped_mass).ravel()
    elongation, orientation = elongation_and_orientation(shape_tensors(fields, ops))
    return ShapeObservables(centre[:, 0], centre[:, 1], area, elongation, orientation)
