"""Per-particle shape observables: centroid, area, shape tensor, elongation, orientation.

Conventions:

* shape tensor R_i = −∫ ∇φ_i ∇φ_iᵀ (the paper's sign). Its eigenvector with the largest
  eigenvalue (the least negative) lies along the particle's elongation. On the structured
  channel it is computed from nodal central differences with the nodal quadrature
  (:meth:`femphase.domains.grid.domain.GridDomain.shape_moments`): that rule has the square symmetry of the lattice, so a
  centred disc has exactly zero elongation. The exact integral of the P1 gradients
  (:func:`femphase.fem.operators.shape_tensors`, any mesh) inherits the bias of the triangulation's diagonals: a
  disc of R = 8 at h = 1 shows r ≈ 0.026 along the diagonal. Both converge as O(h²);
* elongation r = λ1/λ2 − 1 ≥ 0 with ``|λ1| ≥ |λ2|`` the eigenvalues of R (0 for a disc;
  the paper calls λ1/λ2 the aspect ratio, but for an ellipse of similar level sets it is
  (a/b)², docs/model.md);
* orientation θ ∈ (−π/2, π/2]: the angle of the elongation axis from the x axis (nematic);
* centroid: φ-weighted mean ∫xφ/∫φ, x unwrapped about the circular mean over the period
  Lx, so a particle straddling the periodic seam is measured whole;
* area: ∫φ² (the quantity the soft area constraint holds at πR²);
* a particle whose φ reaches 1/2 (:data:`PRESENT_LEVEL`) nowhere has vanished
  (:func:`present`): it has no interface, and its field's "centroid" can lie outside the
  domain, so its x, y, elongation and orientation are NaN (its area is kept);
* wall contact (:func:`wall_contact`): 1 when φ_i exceeds the window threshold
  (``numerics.threshold``, 0.01) on at least one wall dof, else 0. Wall dofs are the dofs of
  the nodes on wall facets: on the structured channel the node rows y = 0 and y = Ly, on a
  meshed channel every node of a boundary facet that is not on the periodic pair (curved
  walls and obstacles included; :func:`wall_dofs`). It is evaluated window by window: a
  window that does not reach a wall has no wall dof, and its particle has no contact.

Shape tensor at a wall. The walls carry the natural condition ∂φ/∂n = 0, so a particle
touching a wall is cut there: φ stays high up to the wall and has no interface along it. R
integrates ∇φ∇φᵀ over the domain only, so it measures the particle's interface *inside* the
domain, not the shape of the particle: the side of a particle pressed against a wall is
missing from R. A particle (R = 8) started 5 from a wall spreads along it: at t = 100 it is
19 nodes wide and 14 tall (φ > 1/2), its R lacks the bottom interface, whose normal is y
(−R_yy is the smaller eigenvalue), and it reports r = 0.68 with a vertical axis (θ = −π/2);
at t = 3000 it is a half-disc 23 wide and 12 tall and reports r = 0.0004, as the arc R sees
has the moments of a whole circle. For particles with ``wall_contact`` = 1, elongation and
orientation therefore describe the interface inside the channel (the wall's contribution is
zero), not an aspect ratio, in either direction; the bias is small while φ at the wall is
small (r = 0.014 for a disc whose tail reaches the wall with φ = 0.06) and of order one for
a particle pressed on the wall. Exclude those particles (``wall_contact == 0``) from shape
statistics, or read them with that meaning.

Integrals are exact for P1 fields (gradients are constant per element); the potential-type
integrals use the nodal (lumped) quadrature of :mod:`femphase.model.energy`.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from femphase.config import Numerics
from femphase.domains.base import Domain
from femphase.domains.layout import Layout
from femphase.state import State

__all__ = ["DEFAULT_THRESHOLD", "PRESENT_LEVEL", "ShapeObservables", "elongation_and_orientation", "present",
           "shape_observables", "wall_contact", "wall_dofs"]


#: The window threshold (``numerics.threshold``'s default): φ above it belongs to a particle.
DEFAULT_THRESHOLD: float = Numerics.threshold


@dataclass(frozen=True)
class ShapeObservables:
    """Arrays of length N: centroid x and y, area ∫φ², elongation r, orientation θ, and
    the wall-contact flag (0 or 1; None where it was not computed)."""

    x: np.ndarray
    y: np.ndarray
    area: np.ndarray
    elongation: np.ndarray
    orientation: np.ndarray
    wall_contact: np.ndarray | None = None


_WALL_DOFS: "weakref.WeakKeyDictionary[Domain, np.ndarray]" = weakref.WeakKeyDictionary()


def wall_dofs(domain: Domain) -> np.ndarray:
    """(n_dofs,) bool: the dofs on a wall. A domain with named wall facets (a meshed
    channel's ``wall_facets``: every boundary facet off the periodic pair, curved walls and
    obstacles included) gives the dofs of their nodes; otherwise (the structured channel) the
    boundary facets of the non-periodic mesh that do not lie on a periodic side x = const at
    the smallest or largest x, i.e. the node rows y = 0 and y = Ly."""
    cached = _WALL_DOFS.get(domain)
    if cached is not None:
        return cached
    mesh = domain.mesh
    facets = getattr(domain, "wall_facets", None)
    if facets is None:
        boundary = mesh.boundary_facets()
        ends = mesh.p[0][mesh.facets[:, boundary]]  # (2, n) x of both ends
        x_low, x_high = mesh.p[0].min(), mesh.p[0].max()
        tolerance = 1e-9 * (x_high - x_low)
        periodic = (np.abs(ends - x_low) <= tolerance).all(axis=0) | (np.abs(ends - x_high) <= tolerance).all(axis=0)
        facets = boundary[~periodic]
    mask = np.zeros(domain.n_dofs, dtype=bool)
    mask[np.asarray(domain.dof_map)[np.unique(mesh.facets[:, facets])]] = True
    _WALL_DOFS[domain] = mask
    return mask


def wall_contact(domain: Domain, layout: Layout, phi: np.ndarray,
                 threshold: float = DEFAULT_THRESHOLD) -> np.ndarray:
    """(N,) int, particle order: 1 when φ_i > ``threshold`` on at least one wall dof of its
    window (:func:`wall_dofs`), else 0."""
    hits = (wall_dofs(domain)[layout.node_index] & (phi > threshold)).astype(np.int64)
    out = np.zeros(len(layout.windows), dtype=np.int64)
    if hits.size:
        out[layout.order] = np.maximum.reduceat(hits, layout.offsets[:-1])
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


#: The level φ_i must reach somewhere for particle i to be present: its interface's, 1/2.
PRESENT_LEVEL = 0.5


def present(layout: Layout, phi: np.ndarray) -> np.ndarray:
    """(N,) bool in particle order: whether φ_i reaches :data:`PRESENT_LEVEL` anywhere. A
    particle that does not has vanished: it has no interface, and its moments measure a faint
    residue. The level is the interface's, not the window threshold, because a residue can
    stay above the threshold: without an area term a disc of R = 3 shrinks away within 50
    time units, and a field of rounding noise (∫φ² ≈ 1e-86) can put a weighted-mean centroid
    outside the channel (y = 111.7 in a 40-high one), or, when exactly zero, break the T1
    counter's triangulation; with model.gamma = 10 a vanished particle's field returns under
    shear as a residue of φ ≤ 0.03, which would give it positions and elongations again."""
    out = np.zeros(len(layout.windows), dtype=bool)
    if phi.size:
        out[layout.order] = layout.reduce(np.maximum, phi) >= PRESENT_LEVEL
    return out


def shape_observables(state: State, threshold: float = DEFAULT_THRESHOLD) -> ShapeObservables:
    """All per-particle shape observables of a state (the domain's rule for the moments:
    :meth:`femphase.domains.base.Domain.shape_moments`); ``threshold`` is the window threshold of
    the wall-contact flag. A vanished particle's (:func:`present`) x, y, elongation and
    orientation are NaN."""
    layout, phi = state.flat()
    area, centre, tensors = state.domain.shape_moments(layout, phi)
    elongation, orientation = elongation_and_orientation(tensors)
    contact = wall_contact(state.domain, layout, phi, threshold)
    gone = ~present(layout, phi)
    x, y, elongation, orientation = (np.where(gone, np.nan, values)
                                     for values in (centre[:, 0], centre[:, 1], elongation, orientation))
    return ShapeObservables(x, y, area, elongation, orientation, contact)
