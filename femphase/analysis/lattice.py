"""Neighbours, order parameters, lattice angle and T1 events of particle centroids.

The paper measures the structure of the suspension on the particles' centroids:

* neighbours are the edges of the Delaunay triangulation of the centroids, periodic in x
  (:func:`periodic_delaunay_pairs`);
* bond order ψ_{m,j} = (1/N_j) Σ_k exp(i m θ_jk) (:func:`bond_order`, m = 6 for Ψ6) and the
  nematic order of neighbouring deformation axes ψ_{2,j} (:func:`nematic_order`); the global
  parameters are ``|(1/N) Σ_j ψ_j|`` per frame (:func:`global_order`), averaged over frames
  (:func:`frame_average`);
* the lattice angle φ ∈ [π/4, π/3] of lanes sliding along x (:func:`lattice_angle`);
* T1 neighbour exchanges as flips of Delaunay edges (:func:`t1_events`,
  :func:`t1_event_times`).

Conventions:

* the channel is [0, Lx) × [0, Ly]: periodic in x with period ``period_x`` = Lx, bounded by
  walls at y = 0 and y = Ly, which are *not* periodic;
* centroids are an ``(N, 2)`` array of (x, y) in the length unit of ``period_x``, with x in
  [0, Lx); particle j is row j, in every frame;
* orientations are nematic angles of the elongation axis from the x axis, in radians,
  θ + π ≡ θ; every returned angle is in radians;
* neighbour pairs are an ``(M, 2)`` int array, one bond per row, ``i < j``, rows unique;
* bond vectors are minimum images in x, which is exact because
  :func:`periodic_delaunay_pairs` only keeps bonds shorter than Lx/2 along x.

Walls: the particles of the rows next to a wall have neighbours on one side only. They are
kept: interior particles need the wall rows to complete their neighbour shells, and for a
lattice with rows along the walls the in-row and inclined bonds of a wall particle are
lattice directions, so a perfect lattice has ψ6 = 1 at the walls too. The edges of the
triangulation along a wall (its convex hull) also join wall particles skipping one that sits
slightly inward, the longest side of a sliver triangle; whether such an edge exists in a
nearly straight row is round-off, and the order parameters leave it out
(``periodic_delaunay_pairs(…, sliver_sides=False)``). In a disordered or noisy configuration
the wall rows can still lower ψ6; exclude them with the ``where`` mask of
:func:`global_order` (e.g. ``margin < y < Ly - margin``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import Delaunay, QhullError

__all__ = ["DEFAULT_AXIS_TOLERANCE", "DEFAULT_LENGTH_CONTRAST", "bond_order", "bond_vectors", "frame_average",
           "frame_order", "global_order", "lattice_angle", "nematic_order", "particle_lattice_angles",
           "periodic_delaunay_pairs", "t1_event_times", "t1_events", "T1Counter"]

#: Bonds within this angle (radians) of the lanes' axis x are in-lane neighbours, and bonds
#: within it of the normal y join particles stacked on top of each other; neither carries the
#: lattice angle (see :func:`particle_lattice_angles`).  π/8 is halfway between the axis and
#: the square-lattice diagonal π/4, the smallest lattice angle to be measured.
DEFAULT_AXIS_TOLERANCE = np.pi / 8

#: An edge flip counts as a T1 once the lost bond is this much longer (relative) than the
#: gained one; nearer to a square, where the two diagonals are equally long, the Delaunay
#: choice flips back and forth with noise (see :func:`t1_event_times`).
DEFAULT_LENGTH_CONTRAST = 0.1

#: A Delaunay edge flip is a T1 only if each of the four triangles of its quadrilateral has
#: at least this area per square of the quadrilateral's longest segment. In a neighbour
#: exchange they are well formed: 0.23 for a rhombus whose diagonals differ by the length
#: contrast, 0.14 for the hexagonal lattice's 60° rhombus. Along a wall the periodic
#: triangulation's hull joins nearly collinear particles of the wall row by slivers (0.01
#: for bumps of 0.6 between particles 14 apart), whose flips exchange no neighbours
#: (docs/decisions/0048-t1-flips-of-slivers-not-counted.md).
SLIVER_AREA = 0.05

_Pair = tuple[int, int]


def periodic_delaunay_pairs(centroids: ArrayLike, period_x: float, *, sliver_sides: bool = True) -> np.ndarray:
    """Neighbour pairs from the Delaunay triangulation, periodic in x only.

    The centroids are triangulated together with their images at x − Lx and x + Lx; the edges
    with at least one original endpoint are mapped back to particle indices and deduplicated.
    Edges whose extent along x exceeds Lx/2 are dropped: the same two particles are then closer
    through the other image, so the edge is not a minimum-image bond.  Such edges only bridge
    an empty gap of more than about half the period along x, never in a dense suspension.
    A particle whose centroid is NaN (a vanished particle,
    :func:`femphase.analysis.shape.present`) takes no part and has no neighbours.

    Parameters
    ----------
    centroids
        ``(N, 2)`` particle centroids (x, y), x in [0, Lx), same length unit as `period_x`.
    period_x
        The period Lx of the channel along x.
    sliver_sides
        False: without the longest side of every sliver triangle (area below
        :data:`SLIVER_AREA` times that side squared), whose ends have the third particle
        between them: the neighbours of the order parameters (:func:`frame_order`). Along a
        wall row such a side exists or not by round-off (rows level to 1e-7 gave one or none
        with the images in another order); the T1 counter, whose flips of slivers
        :func:`_is_sliver` tells apart, takes the triangulation's every edge.

    Returns
    -------
    np.ndarray
        ``(M, 2)`` int array of unique pairs, ``i < j`` in each row, rows sorted.
    """
    centroids = _as_centroids(centroids)
    finite = np.isfinite(centroids).all(axis=1)
    if not finite.all():
        kept = np.flatnonzero(finite)
        pairs = (periodic_delaunay_pairs(centroids[kept], period_x, sliver_sides=sliver_sides) if kept.size > 1
                 else np.zeros((0, 2), dtype=int))
        return kept[pairs].reshape(-1, 2)
    n_particles = len(centroids)
    images = np.concatenate(
        [centroids + (shift, 0.0) for shift in (0.0, -period_x, period_x)]
    )
    sliver = np.zeros((0, 2), dtype=int)
    try:
        simplices = Delaunay(images).simplices
        edges = simplices[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
        if not sliver_sides:
            sliver = _sliver_sides(images, simplices)
    except QhullError:
        # every centroid on one line (e.g. a single lane): the triangulation is flat, and
        # the neighbours are the consecutive points along the line
        edges = _collinear_edges(images)
    codes = _pair_codes(edges, images, period_x, n_particles)
    if sliver.size:
        codes = np.setdiff1d(codes, _pair_codes(sliver, images, period_x, n_particles))
    return np.stack(np.divmod(codes, n_particles), axis=1)


def _pair_codes(edges: np.ndarray, images: np.ndarray, period_x: float, n_particles: int) -> np.ndarray:
    """The particle pairs (i, j), i < j, of edges between ``images`` with at least one
    original endpoint and at most Lx/2 long along x, as sorted unique codes i·N + j."""
    extent_x = np.abs(images[edges[:, 1], 0] - images[edges[:, 0], 0])
    edges = edges[(edges < n_particles).any(axis=1) & (extent_x <= period_x / 2)]
    pairs = np.sort(edges % n_particles, axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    # unique rows through one integer per pair, i·N + j (sorted as the rows are): np.unique
    # with axis=0 took 6× as long, and the T1 counter triangulates every output.t1_interval
    return np.unique(pairs[:, 0] * n_particles + pairs[:, 1])


def _sliver_sides(points: np.ndarray, simplices: np.ndarray) -> np.ndarray:
    """(k, 2): the longest side of every triangle of less than :data:`SLIVER_AREA` times
    that side squared."""
    corners = points[simplices]
    sides = corners[:, [1, 2, 0]] - corners  # side k runs from corner k to corner k + 1
    squares = np.sum(sides**2, axis=2)
    area = 0.5 * np.abs(sides[:, 0, 0] * sides[:, 1, 1] - sides[:, 0, 1] * sides[:, 1, 0])
    thin = np.flatnonzero(area < SLIVER_AREA * squares.max(axis=1))
    longest = squares[thin].argmax(axis=1)
    return np.stack([simplices[thin, longest], simplices[thin, (longest + 1) % 3]], axis=1)


def _collinear_edges(points: np.ndarray) -> np.ndarray:
    """Edges between consecutive points along the line through collinear ``points``
    (coincident points are joined to one of them)."""
    if len(points) < 2:
        return np.zeros((0, 2), dtype=int)
    offsets = points - points.mean(axis=0)
    direction = np.linalg.svd(offsets, full_matrices=False)[2][0]
    order = np.argsort(offsets @ direction, kind="stable")
    return np.stack([order[:-1], order[1:]], axis=1)


def bond_vectors(centroids: ArrayLike, period_x: float, pairs: ArrayLike) -> np.ndarray:
    """Minimum-image vectors from particle ``pairs[:, 0]`` to particle ``pairs[:, 1]``.

    Returns an ``(M, 2)`` float array in the length unit of the centroids, with the x
    component in [−Lx/2, Lx/2].
    """
    centroids = _as_centroids(centroids)
    pairs = _as_pairs(pairs)
    vectors = centroids[pairs[:, 1]] - centroids[pairs[:, 0]]
    vectors[:, 0] -= period_x * np.round(vectors[:, 0] / period_x)
    return vectors


def bond_order(
    centroids: ArrayLike,
    period_x: float,
    pairs: ArrayLike | None = None,
    m: int = 6,
) -> np.ndarray:
    """Per-particle m-fold bond order ψ_{m,j} = (1/N_j) Σ_k exp(i m θ_jk).

    θ_jk is the angle from the x axis to the bond from particle j to its neighbour k, and N_j
    the number of neighbours of j.  `pairs` defaults to :func:`periodic_delaunay_pairs`.

    Returns
    -------
    np.ndarray
        Complex array of length N; NaN for a particle without neighbours (e.g. one that
        coincides with another and so is not a vertex of the triangulation).
    """
    centroids = _as_centroids(centroids)
    pairs = periodic_delaunay_pairs(centroids, period_x) if pairs is None else _as_pairs(pairs)
    vectors = bond_vectors(centroids, period_x, pairs)
    angle = np.arctan2(vectors[:, 1], vectors[:, 0])
    # the bond seen from its second particle points the other way, θ_kj = θ_jk + π, which
    # matters for odd m
    return _neighbour_mean(
        pairs, np.exp(1j * m * angle), np.exp(1j * m * (angle + np.pi)), len(centroids)
    )


def nematic_order(
    orientations: ArrayLike, pairs: ArrayLike, n_particles: int
) -> np.ndarray:
    """Per-particle nematic order of neighbouring deformation axes.

    ψ_{2,j} = (1/N_j) Σ_k exp(2i(θ_j − θ_k)): θ^d_jk = θ_j − θ_k is the angle between the
    deformation axes of particle j and its neighbour k, doubled because the axes are nematic
    (θ and θ + π are the same axis).  (The paper prints exp(6iθ^d_jk); the 6 is a typo.)
    ψ_{2,j} = 1 when j is aligned with all its neighbours, whatever the common direction;
    a neighbour at right angles contributes −1.  This is the local alignment the paper
    describes, not the alignment with a global director, ``|⟨exp(2iθ_j)⟩|``.

    Parameters
    ----------
    orientations
        Length-N nematic angles θ_j of the elongation axes from the x axis (radians).
    pairs
        ``(M, 2)`` neighbour pairs, e.g. from :func:`periodic_delaunay_pairs`.
    n_particles
        N, the number of particles (``len(orientations)``).

    Returns
    -------
    np.ndarray
        Complex array of length N (NaN for a particle without neighbours).
    """
    orientations = np.asarray(orientations, dtype=float)
    if orientations.shape != (n_particles,):
        raise ValueError(
            f"orientations must have shape ({n_particles},); got {orientations.shape}"
        )
    pairs = _as_pairs(pairs)
    alignment = np.exp(2j * (orientations[pairs[:, 0]] - orientations[pairs[:, 1]]))
    return _neighbour_mean(pairs, alignment, alignment.conj(), n_particles)


def global_order(psi: ArrayLike, where: ArrayLike | None = None) -> float:
    """``|(1/N) Σ_j ψ_j|``, the global order parameter of one frame.

    `where` is an optional boolean mask of the particles to average over (e.g. away from the
    walls); particles with NaN ψ_j (no neighbours) are always left out.
    """
    psi = np.asarray(psi, dtype=complex)
    chosen = ~np.isnan(psi)
    if where is not None:
        chosen &= np.asarray(where, dtype=bool)
    if not chosen.any():
        raise ValueError("no particle with neighbours to average the order parameter over")
    return float(np.abs(psi[chosen].mean()))


def frame_average(values: ArrayLike) -> tuple[float, float]:
    """Mean and standard deviation of a per-frame quantity over the frames given.

    The paper averages Ψ6 and Ψ2^L over the last 50 of 250 frames: pass those frames' values
    (e.g. ``[global_order(psi) for psi in last_frames]``).  The standard deviation is that of
    the per-frame values (ddof = 0), i.e. the size of the fluctuations, not the error of the
    mean.
    """
    values = np.asarray(values, dtype=float).ravel()
    if values.size == 0:
        raise ValueError("frame_average needs at least one frame")
    return float(values.mean()), float(values.std())


def particle_lattice_angles(
    centroids: ArrayLike,
    period_x: float,
    pairs: ArrayLike | None = None,
    *,
    axis_tolerance: float = DEFAULT_AXIS_TOLERANCE,
) -> np.ndarray:
    """Per-particle lattice angle φ_j of lanes along x (radians).

    Consider lanes along x with in-lane spacing a and lane spacing h, the lane above having
    slid by s along x from the hexagonal stacking.  A particle has two inclined bonds to the
    lane above, at angles (folded into [0, π/2]) α = atan(h / (a/2 + s)) and
    β = atan(h / (a/2 − s)) for 0 ≤ s ≤ a/2.  The hexagonal lattice (s = 0, h = a√3/2) has
    α = β = π/3.  As the lanes slide, α falls and β rises until the T1 at s = a/2, where the
    lanes are stacked into a rectangular lattice (square in the paper, whose elongated
    particles make h = a): β = π/2, and α = atan(h/a) (π/4 for the square) is the angle of the
    diagonal that flips.  After the flip the new diagonal plays α and rises back to π/3.  The
    lattice angle of the paper, φ ∈ [π/4, π/3], is therefore α: the smaller inclination of
    the bonds to a neighbouring lane.

    So, for each particle and each side (neighbours above, neighbours below):

    1. fold every bond's angle into [0, π/2] (its inclination to the lanes);
    2. drop bonds within `axis_tolerance` of the x axis (in-lane neighbours) and of the y axis
       (a particle stacked on top of another: β near the T1; the Delaunay diagonal of that
       near-square cell may belong to the neighbours, leaving only the vertical bond, which
       carries no lattice angle);
    3. take the smallest remaining inclination, α of that side.

    φ_j is the mean over the sides that have an inclined bond.  Each side is a single lane
    interface, so lanes in different phases of sliding are not mixed within a side.

    With positional noise the minimum of two nearly equal angles is biased low, by about half
    the angular noise of a bond near the hexagonal lattice.

    Returns
    -------
    np.ndarray
        Length-N array; NaN for a particle without inclined bonds.
    """
    centroids = _as_centroids(centroids)
    n_particles = len(centroids)
    pairs = periodic_delaunay_pairs(centroids, period_x) if pairs is None else _as_pairs(pairs)
    vectors = bond_vectors(centroids, period_x, pairs)
    # every bond, seen from each of its two particles
    owners = pairs.T.ravel()
    outgoing = np.concatenate([vectors, -vectors])
    inclination = np.arctan2(np.abs(outgoing[:, 1]), np.abs(outgoing[:, 0]))
    inclined = (inclination > axis_tolerance) & (inclination < np.pi / 2 - axis_tolerance)
    above = (outgoing[:, 1] > 0).astype(int)

    smallest = np.full((n_particles, 2), np.inf)
    np.minimum.at(smallest, (owners[inclined], above[inclined]), inclination[inclined])
    found = np.isfinite(smallest)
    n_sides = found.sum(axis=1)
    return np.divide(
        np.where(found, smallest, 0.0).sum(axis=1),
        n_sides,
        out=np.full(n_particles, np.nan),
        where=n_sides > 0,
    )


def lattice_angle(
    centroids: ArrayLike,
    period_x: float,
    pairs: ArrayLike | None = None,
    *,
    axis_tolerance: float = DEFAULT_AXIS_TOLERANCE,
) -> float:
    """The lattice angle φ of one frame (radians): π/3 hexagonal, π/4 square at the T1.

    The median of :func:`particle_lattice_angles` over the particles that have inclined
    bonds; the median ignores the few wall or defect particles whose bonds are not those of
    the lattice.  (:func:`frame_order`, what runs write, gives NaN instead of raising.)

    Raises
    ------
    ValueError
        If no particle has an inclined bond.
    """
    angles = particle_lattice_angles(
        centroids, period_x, pairs, axis_tolerance=axis_tolerance
    )
    if np.isnan(angles).all():
        raise ValueError(
            "no inclined bonds: every bond is within axis_tolerance of the x or y axis"
        )
    return float(np.nanmedian(angles))


def frame_order(centroids: ArrayLike, orientation: ArrayLike, period_x: float) -> dict:
    """One frame's order: per particle ``|ψ6|`` and ``|ψ2|`` ("psi6_abs", "psi2_abs"), and Ψ6, Ψ2^L
    and the lattice angle (radians).

    Never raises on a valid configuration: NaN for fewer than 3 particles, Ψ6 and Ψ2^L NaN
    when no particle has a neighbour, and the lattice angle NaN when no bond is inclined
    (e.g. a rectangular layout whose bonds all lie within the axis tolerance of x or y, as
    at t = 0 of a run started on such a lattice), so a run's "order" observable records the
    frame instead of aborting."""
    centroids = _as_centroids(centroids)
    n = len(centroids)
    if n < 3:
        nan = np.full(n, np.nan)
        return {"psi6_abs": nan, "psi2_abs": nan, "Psi6": np.nan, "Psi2": np.nan, "lattice_angle": np.nan}
    pairs = periodic_delaunay_pairs(centroids, period_x, sliver_sides=False)
    psi6 = bond_order(centroids, period_x, pairs)
    psi2 = nematic_order(orientation, pairs, n)
    angles = particle_lattice_angles(centroids, period_x, pairs)
    return {"psi6_abs": np.abs(psi6), "psi2_abs": np.abs(psi2), "Psi6": _global_or_nan(psi6),
            "Psi2": _global_or_nan(psi2),
            "lattice_angle": float(np.nanmedian(angles)) if not np.isnan(angles).all() else np.nan}


def _global_or_nan(psi: np.ndarray) -> float:
    """:func:`global_order`, NaN when no particle has a neighbour."""
    return global_order(psi) if not np.isnan(psi).all() else np.nan


def t1_events(
    pairs_before: ArrayLike, pairs_after: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Bonds lost and gained between two frames.

    A T1 neighbour exchange shows as one lost and one gained pair; :func:`t1_event_times`
    counts them robustly over a sequence of frames.  Returns ``(lost, gained)``, each a
    ``(K, 2)`` int array with ``i < j`` in each row, rows sorted.
    """
    before, after = _pair_set(pairs_before), _pair_set(pairs_after)
    return _pair_array(before - after), _pair_array(after - before)


def t1_event_times(
    centroid_frames: Sequence[ArrayLike],
    times: ArrayLike,
    period_x: float,
    *,
    length_contrast: float = DEFAULT_LENGTH_CONTRAST,
) -> np.ndarray:
    """Times of the T1 events in a sequence of frames.

    A T1 is one Delaunay edge flip: the bond (a, b) is lost and the bond (c, d) gained, where
    a-c-b-d is a quadrilateral whose four sides are bonds both before and after.  Lost and
    gained bonds are matched into flips greedily; changes that match no flip (the convex hull
    at a wall changing, several coupled flips in one triangle fan) are not counted, nor are
    flips of a quadrilateral with a sliver triangle (:data:`SLIVER_AREA`: the nearly
    collinear particles of a wall row, which exchange no neighbours).

    A square cell is degenerate: its two diagonals are equally long, and the Delaunay choice
    between them flips back and forth with any noise.  Flips are therefore counted with
    hysteresis against a reference topology.  A flip counts, at the time of the first frame in
    which the lost diagonal is at least ``1 + length_contrast`` times as long as the gained
    one; until then the reference keeps the old diagonal, so a flip that reverts before
    becoming decisive is not counted at all, and a flip that becomes decisive over several
    frames is counted once.  Several T1s in one frame give repeated times.

    Parameters
    ----------
    centroid_frames
        Sequence of ``(N, 2)`` centroids, same particle order in every frame.
    times
        Time of each frame (any unit; returned in the same unit).
    period_x
        The period Lx of the channel along x.
    length_contrast
        Relative excess length of the lost over the gained diagonal that makes a flip count.

    Returns
    -------
    np.ndarray
        Sorted times of the T1 events; its length is the number of T1 events.
    """
    times = np.asarray(times, dtype=float)
    if len(times) != len(centroid_frames):
        raise ValueError(
            f"{len(centroid_frames)} frames but {len(times)} times; need one time per frame"
        )
    if len(times) == 0:
        return np.empty(0)

    counter = T1Counter(centroid_frames[0], period_x, length_contrast=length_contrast)
    event_times = []
    for time, centroids in zip(times[1:], centroid_frames[1:]):
        event_times += [time] * counter.update(centroids)
    return np.sort(np.asarray(event_times, dtype=float))


class T1Counter:
    """Counts T1 events frame by frame, with the hysteresis of :func:`t1_event_times`."""

    def __init__(
        self, centroids: ArrayLike, period_x: float, *, length_contrast: float = DEFAULT_LENGTH_CONTRAST
    ) -> None:
        self.period_x = period_x
        self.length_contrast = length_contrast
        self.reference = _pair_set(periodic_delaunay_pairs(centroids, period_x))
        self.count = 0

    def update(self, centroids: ArrayLike) -> int:
        """Take the next frame's centroids; return how many T1 events became decisive."""
        current = _pair_set(periodic_delaunay_pairs(centroids, self.period_x))
        reference = self.reference
        flips = [flip for flip in _edge_flips(reference - current, current - reference, reference & current)
                 if not _is_sliver(centroids, self.period_x, *flip)]
        undecided = [
            (lost, gained)
            for lost, gained in flips
            if not _is_decisive(centroids, self.period_x, lost, gained, self.length_contrast)
        ]
        self.reference = (current - {gained for _, gained in undecided}) | {
            lost for lost, _ in undecided
        }
        events = len(flips) - len(undecided)
        self.count += events
        return events

    def snapshot(self) -> dict[str, np.ndarray]:
        """The counter's state as arrays (for a checkpoint): count and reference bonds."""
        return {"t1_count": np.array([self.count]),
                "t1_reference": np.array(sorted(self.reference), dtype=np.int64).reshape(-1, 2)}

    @classmethod
    def restore(cls, snapshot: dict[str, np.ndarray], period_x: float, *,
                length_contrast: float = DEFAULT_LENGTH_CONTRAST) -> "T1Counter":
        """The counter of :meth:`snapshot`, continuing where it stopped."""
        counter = cls.__new__(cls)
        counter.period_x, counter.length_contrast = period_x, length_contrast
        counter.reference = {(int(a), int(b)) for a, b in snapshot["t1_reference"]}
        counter.count = int(snapshot["t1_count"][0])
        return counter


def _edge_flips(
    lost: set[_Pair], gained: set[_Pair], kept: set[_Pair]
) -> list[tuple[_Pair, _Pair]]:
    """Match lost with gained bonds into edge flips (see :func:`t1_event_times`)."""
    flips = []
    unmatched = set(gained)
    for old in sorted(lost):
        new = next((new for new in sorted(unmatched) if _is_flip(old, new, kept)), None)
        if new is not None:
            flips.append((old, new))
            unmatched.remove(new)
    return flips


def _is_flip(old: _Pair, new: _Pair, kept: set[_Pair]) -> bool:
    (a, b), (c, d) = old, new
    sides = ((a, c), (a, d), (b, c), (b, d))
    return len({a, b, c, d}) == 4 and all(
        (min(side), max(side)) in kept for side in sides
    )


def _is_sliver(centroids: ArrayLike, period_x: float, lost: _Pair, gained: _Pair) -> bool:
    """Whether the quadrilateral a-c-b-d of the flip of ``lost`` (a, b) into ``gained`` (c, d)
    has a triangle of less than :data:`SLIVER_AREA` times its longest segment squared."""
    (a, b), (c, d) = lost, gained
    ab, ac, ad = bond_vectors(centroids, period_x, [(a, b), (a, c), (a, d)])
    corners = np.array([[0.0, 0.0], ab, ac, ad])  # a, b, c, d, unwrapped around a
    longest = max(float(np.sum((corners[i] - corners[j]) ** 2)) for i in range(4) for j in range(i))

    def area(i: int, j: int, k: int) -> float:
        u, v = corners[j] - corners[i], corners[k] - corners[i]
        return 0.5 * abs(u[0] * v[1] - u[1] * v[0])

    return min(area(0, 1, 2), area(0, 1, 3), area(2, 3, 0), area(2, 3, 1)) < SLIVER_AREA * longest


def _is_decisive(
    centroids: ArrayLike, period_x: float, lost: _Pair, gained: _Pair, length_contrast: float
) -> bool:
    lost_length, gained_length = np.linalg.norm(
        bond_vectors(centroids, period_x, [lost, gained]), axis=1
    )
    return bool(lost_length >= (1 + length_contrast) * gained_length)


def _neighbour_mean(
    pairs: np.ndarray, to_first: np.ndarray, to_second: np.ndarray, n_particles: int
) -> np.ndarray:
    """Mean over each particle's bonds; bond p contributes to_first[p] to particle
    pairs[p, 0] and to_second[p] to particle pairs[p, 1]."""
    owners = pairs.T.ravel()
    contributions = np.concatenate([to_first, to_second])
    sums = np.bincount(owners, contributions.real, n_particles) + 1j * np.bincount(
        owners, contributions.imag, n_particles
    )
    counts = np.bincount(owners, minlength=n_particles)
    return np.divide(
        sums, counts, out=np.full(n_particles, np.nan, dtype=complex), where=counts > 0
    )


def _as_centroids(centroids: ArrayLike) -> np.ndarray:
    centroids = np.array(centroids, dtype=float)
    if centroids.ndim != 2 or centroids.shape[1] != 2:
        raise ValueError(f"centroids must have shape (N, 2); got {centroids.shape}")
    return centroids


def _as_pairs(pairs: ArrayLike) -> np.ndarray:
    return np.asarray(pairs, dtype=int).reshape(-1, 2)


def _pair_set(pairs: ArrayLike) -> set[_Pair]:
    return set(map(tuple, np.sort(_as_pairs(pairs), axis=1).tolist()))


def _pair_array(pairs: set[_Pair]) -> np.ndarray:
    return np.array(sorted(pairs), dtype=int).reshape(-1, 2)
