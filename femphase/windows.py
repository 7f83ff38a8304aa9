"""Per-particle windows: each field is computed only on a set of dofs that covers it.

As in the paper's supplement, a window covers the nodes where φ > threshold plus a margin
(4 lattice units by default) on every side; it grows when the margin runs short, shrinks
when it is far too long, follows the particle, wraps periodically in x and ends at the walls.
Outside its window a field is zero, so a window's linear system is the principal submatrix
of the full-domain system on the window's dofs (homogeneous Dirichlet data on the window's
artificial edges, natural Neumann on the walls).

A window is a hashable description that its :class:`~femphase.domain.Domain` turns into
dofs. Two kinds exist:

* :class:`Window`, a rectangular block of the structured channel's node lattice. Its
  submatrix depends only on :meth:`Window.key`, so windows of one shape share one matrix,
  one solver and one multi-right-hand-side solve (the structured fast path);
* :class:`Box`, the dofs of any mesh inside an axis-aligned box (periodic in x).

:class:`Layout` concatenates all windows' fields into one flat vector, grouped by key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Hashable, Sequence

import numpy as np

# -- rectangular windows of the structured channel ---------------------------------------

@dataclass(frozen=True)
class Window:
    """Rows iy0 … iy0+ny−1 and columns ix0 … ix0+nx−1 (mod the lattice's nx) of the channel's
    node lattice; its field is stored row by row (x fastest). A window with nx equal to the
    lattice's spans the whole periodic width (then ix0 = 0)."""

    iy0: int
    ny: int
    ix0: int
    nx: int

    @property
    def shape(self) -> tuple[int, int]:
        return (self.ny, self.nx)

    def rows(self) -> np.ndarray:
        return np.arange(self.iy0, self.iy0 + self.ny)

    def columns(self, lattice_nx: int) -> np.ndarray:
        return (self.ix0 + np.arange(self.nx)) % lattice_nx

    def key(self, lattice_ny: int, lattice_nx: int, alternating: bool) -> tuple:
        """Everything the window's submatrix depends on: shape, walls touched, periodicity,
        and (alternating diagonals only) the chequerboard parity."""
        parity = (self.ix0 + self.iy0) % 2 if alternating else 0
        # nx first: windows of one width are then contiguous in a layout, and a row shift
        # transforms them in one call (femphase.advection.row_runs)
        return (self.nx, self.ny, self.iy0 == 0, self.iy0 + self.ny == lattice_ny, self.nx == lattice_nx, parity)


@dataclass(frozen=True)
class WindowPolicy:
    """How rectangular windows follow their fields (all lengths in nodes of the lattice).

    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      nodes kept between the particle and a window edge (the paper: 4 sites)
    room        extra nodes a new window leaves on each side, so it need not move every step
    quantum     window sizes are rounded up to a multiple of this, so that few distinct
                shapes (and solvers) exist
    enabled     False: every window is the whole channel (full-mesh mode)
    """

    threshold: float = 0.01
    margin: int = 4
    room: int = 1
    quantum: int = 4
    enabled: bool = True

    @classmethod
    def for_spacing(cls, h: float, *, threshold: float = 0.01, margin: float = 4.0,
                    enabled: bool = True) -> "WindowPolicy":
        """A policy whose margin is ``margin`` lattice units (not nodes) at spacing h."""
        margin_nodes = math.ceil(margin / h - 1e-9)
        return cls(threshold=threshold, margin=margin_nodes, room=max(1, math.ceil(margin_nodes / 4)),
                   quantum=max(4, 2 * math.ceil(1.0 / h)), enabled=enabled)

    @property
    def longest_margin(self) -> int:
        """The longest margin a window keeps before it shrinks."""
        return self.margin + 2 * self.room + self.quantum

    def cover(self, rows: tuple[int, int], cols: tuple[int, int], lattice: tuple[int, int]) -> Window:
        """A window around the occupied node box rows × cols (inclusive; cols may exceed nx)
        on a lattice of (ny, nx) nodes."""
        lattice_ny, lattice_nx = lattice
        if not self.enabled:
            return Window(0, lattice_ny, 0, lattice_nx)
        pad = self.margin + self.room
        ny = _round_up(rows[1] - rows[0] + 1 + 2 * pad, self.quantum)
        nx = _round_up(cols[1] - cols[0] + 1 + 2 * pad, self.quantum)
        iy0 = rows[0] - (ny - (rows[1] - rows[0] + 1)) // 2
        # clip at the walls: the window ends there, it does not slide inward
        top = min(iy0 + ny, lattice_ny)
        iy0 = max(iy0, 0)
        ny = top - iy0
        if nx >= lattice_nx:
            return Window(int(iy0), int(ny), 0, int(lattice_nx))
        ix0 = (cols[0] - (nx - (cols[1] - cols[0] + 1)) // 2) % lattice_nx
        return Window(int(iy0), int(ny), int(ix0), int(nx))

    def occupied(self, layout: "GridLayout", phi: np.ndarray) -> np.ndarray:
        """(windows, 4), layout order: the first and last row and the first and last column
        (local nodes) where each window's field exceeds the threshold; −1 in all four for a
        window where it nowhere does (:func:`femphase.kernels.occupied_boxes`, one compiled
        scan of all windows)."""
        from . import kernels  # numba loads only where a scene needs it

        return kernels.occupied_boxes(phi, layout.offsets, layout.corners, phi.dtype.type(self.threshold))

    def misfits(self, layout: "GridLayout", phi: np.ndarray, lattice: tuple[int, int],
                boxes: np.ndarray | None = None) -> np.ndarray:
        """For the fields ``phi`` (layout order) on the layout's windows: which need another
        window (bool per window, layout order); ``boxes``: :meth:`occupied` of ``phi``, if
        known.

        A window fits while every margin not at a wall lies within [margin, longest_margin];
        full-width windows are always re-examined (the particle may fit a narrower one). The
        check runs after every substep: from the occupied boxes of one compiled scan and the
        windows' corners, on the random packing at γ̇ = 1 it costs 0.10–0.14 ms against 0.42
        for numpy's boolean reductions group by group (benchmarks/README.md, "Session 15")."""
        n = len(layout.windows)
        if not self.enabled or n == 0:
            return np.zeros(n, dtype=bool)
        boxes = self.occupied(layout, phi) if boxes is None else boxes
        iy0, ny, nx = layout.corners[:, 0], layout.corners[:, 1], layout.corners[:, 3]
        # left, right, bottom, top (nodes); none is needed at a wall
        margins = np.stack([boxes[:, 2], nx - 1 - boxes[:, 3], boxes[:, 0], ny - 1 - boxes[:, 1]], axis=1)
        bad = (margins < self.margin) | (margins > self.longest_margin)
        bad[:, 2] &= iy0 != 0
        bad[:, 3] &= iy0 + ny != lattice[0]
        return (bad.any(axis=1) | (nx == lattice[1])) & (boxes[:, 0] >= 0)

    def fit(self, phi: np.ndarray, window: Window, lattice: tuple[int, int],
            box: np.ndarray | None = None) -> Window:
        """The window ``phi`` (ny, nx on ``window``) should live on next; ``box``: its row of
        :meth:`occupied`, if known."""
        from . import kernels

        lattice_ny, lattice_nx = lattice
        if box is None:
            corners = np.array([[window.iy0, window.ny, window.ix0, window.nx]])
            box = kernels.occupied_boxes(phi.ravel(), np.array([0, phi.size]), corners, phi.dtype.type(self.threshold))[0]
        if box[0] < 0:
            return window
        row_span = (int(box[0]), int(box[1]))
        rows = (window.iy0 + row_span[0], window.iy0 + row_span[1])
        if window.nx == lattice_nx:
            c0, c1 = _circular_extent((phi > self.threshold).any(axis=0))
            if c1 - c0 + 1 + 2 * (self.margin + self.room) + self.quantum <= lattice_nx:
                return self.cover(rows, (c0, c1), lattice)
            # the particle needs the whole width; its rows must still follow it (a channel
            # narrower than a window: the y-extent must not freeze)
            if self._rows_fit(window, row_span, lattice_ny):
                return window
            return self.cover(rows, (0, lattice_nx - 1), lattice)
        cols = (window.ix0 + int(box[2]), window.ix0 + int(box[3]))
        return self._recentred(window, row_span, cols, lattice) or self.cover(rows, cols, lattice)

    def _recentred(self, window: Window, row_span: tuple[int, int], cols: tuple[int, int],
                   lattice: tuple[int, int]) -> Window | None:
        """``window`` moved to centre its particle (first and last occupied row ``row_span``,
        local; occupied columns ``cols``, lattice), its shape kept, if the centred margins
        lie in [margin, longest_margin] and it touches the same walls; else None. Under flow a particle
        drifts out of its window sideways (the advection moves windows by whole nodes and
        leaves the rest of each row's shift to the field): on the random packing at γ̇ = 1,
        90 % of misfits. A fresh cover rounds the particle's size to another shape as often
        as not, and a new shape costs a new layout (groups rebuilt), where a window of the
        same shape only moves the layout (:meth:`Layout.moved`)."""
        lattice_ny, lattice_nx = lattice
        rows = (window.iy0 + row_span[0], window.iy0 + row_span[1])
        if window.iy0 == 0 or window.iy0 + window.ny == lattice_ny:  # at a wall: those rows stay
            if not self._rows_fit(window, row_span, lattice_ny):
                return None
            iy0 = window.iy0
        else:
            iy0 = self._centred_start(rows, window.ny)
            if iy0 is None or iy0 <= 0 or iy0 + window.ny >= lattice_ny:
                return None
        ix0 = self._centred_start(cols, window.nx)
        return None if ix0 is None else Window(int(iy0), window.ny, int(ix0 % lattice_nx), window.nx)

    def _rows_fit(self, window: Window, row_span: tuple[int, int], lattice_ny: int) -> bool:
        """Whether the margins of the occupied rows ``row_span`` (first, last; local) lie in
        [margin, longest_margin] on every side of ``window`` not at a wall (none is needed
        there)."""
        at_wall = (window.iy0 == 0, window.iy0 + window.ny == lattice_ny)
        margins = (row_span[0], window.ny - 1 - row_span[1])
        return all(wall or self.margin <= m <= self.longest_margin for wall, m in zip(at_wall, margins))

    def _centred_start(self, occupied: tuple[int, int], length: int) -> int | None:
        """The first node of ``length`` nodes centred on the occupied span, if both margins
        then lie in [margin, longest_margin]."""
        spare = length - (occupied[1] - occupied[0] + 1)
        low = spare // 2
        return occupied[0] - low if self.margin <= low and spare - low <= self.longest_margin else None


def window_corners(windows: Sequence[Window]) -> np.ndarray:
    """(windows, 4) int64: iy0, ny, ix0, nx of every window, in the given order (also the
    channel's checkpoint format)."""
    return np.array([[w.iy0, w.ny, w.ix0, w.nx] for w in windows], dtype=np.int64).reshape(-1, 4)


def _round_up(n: int, quantum: int) -> int:
    return -(-n // quantum) * quantum


def _circular_extent(occupied: np.ndarray) -> tuple[int, int]:
    """First and last index (last may be ≥ n) of the shortest circular run covering all True."""
    n = occupied.size
    hits = np.flatnonzero(occupied)
    if hits.size == n:
        return 0, n - 1
    gaps = np.diff(np.append(hits, hits[0] + n))  # distance from each hit to the next one
    widest = int(np.argmax(gaps))
    start = hits[(widest + 1) % hits.size]
    end = hits[widest] + (n if hits[widest] < start else 0)
    return int(start), int(end)


def pad_window(phi: np.ndarray, window: Window, lattice: tuple[int, int], width: int) -> np.ndarray:
    """phi (..., ny, nx) with ``width`` extra nodes on every side: mirrored at a wall (the
    Neumann condition), periodic across the seam of a full-width window, zero beyond a
    window's artificial edge (the field is zero there by definition). Leading axes stack
    fields on windows of the same key."""
    ny, nx = phi.shape[-2:]
    # filled slice by slice: np.pad's generality costs ~0.3 ms a call, and this runs for
    # every window group at every frame
    out = np.zeros(phi.shape[:-2] + (ny + 2 * width, nx + 2 * width), dtype=phi.dtype)
    out[..., width:width + ny, width:width + nx] = phi
    if window.iy0 == 0:  # reflected without repeating the wall row, as np.pad's "reflect"
        out[..., :width, width:width + nx] = phi[..., width:0:-1, :]
    if window.iy0 + window.ny == lattice[0]:
        out[..., width + ny:, width:width + nx] = phi[..., -2:-2 - width:-1, :]
    if window.nx == lattice[1]:
        out[..., :width] = out[..., nx:nx + width]
        out[..., width + nx:] = out[..., width:2 * width]
    return out


def transfer(phi: np.ndarray, old: Window, new: Window, lattice_nx: int) -> np.ndarray:
    """The field ``phi`` (ny, nx on ``old``) on the nodes of ``new``; zero where ``old`` had none."""
    out = np.zeros((new.ny, new.nx), dtype=phi.dtype)
    row_lo, row_hi = max(old.iy0, new.iy0), min(old.iy0 + old.ny, new.iy0 + new.ny)
    if row_lo >= row_hi:
        return out
    local_old = (new.columns(lattice_nx) - old.ix0) % lattice_nx
    keep = local_old < old.nx
    out[row_lo - new.iy0:row_hi - new.iy0, keep] = phi[row_lo - old.iy0:row_hi - old.iy0][:, local_old[keep]]
    return out


# -- box windows of any mesh --------------------------------------------------------------

@dataclass(frozen=True, order=True)
class Box:
    """x from ``x0`` over ``width`` (mod the period; ``width == period``: the whole period),
    y from ``y0`` to ``y1`` (length units). Its dofs are the mesh's dofs inside it."""

    x0: float
    width: float
    y0: float
    y1: float

    def contains(self, x: np.ndarray, y: np.ndarray, period: float) -> np.ndarray:
        return (local_x(x, self.x0, period) <= self.width) & (y >= self.y0) & (y <= self.y1)


def local_x(x: np.ndarray, x0, period: float) -> np.ndarray:
    """x measured from a box's left edge x0 along +x, in [0, period)."""
    return np.mod(x - x0, period)


@dataclass(frozen=True)
class BoxPolicy:
    """How boxes follow their fields (lengths in the mesh's unit).

    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      length kept between the particle and a box edge (the paper: 4 sites)
    room        extra length a refitted box leaves on each side
    slack       box sizes are rounded up to a multiple of this (hysteresis: a box fits while
                every margin is within [margin, margin + 2 room + slack + motion allowance])
    lookahead   steps of motion a refitted box leaves room for ahead of a moving particle
                (up to four margins), so that its solvers last several steps
    enabled     False: every box is the whole domain (full-mesh mode)
    """

    threshold: float = 0.01
    margin: float = 4.0
    room: float = 1.0
    slack: float = 4.0
    lookahead: float = 12.0
    enabled: bool = True

    @classmethod
    def for_spacing(cls, h: float, *, threshold: float = 0.01, margin: float = 4.0,
                    enabled: bool = True) -> "BoxPolicy":
        """The structured policy's margins at mesh spacing h (room h, slack ≥ 4h)."""
        margin = h * math.ceil(margin / h - 1e-9)
        return cls(threshold=threshold, margin=margin, room=max(h, margin / 4),
                   slack=max(4.0 * h, margin), enabled=enabled)

    def allowance(self, step: np.ndarray) -> np.ndarray:
        """Room ahead of a particle moving by ``step`` per time step (any shape)."""
        step = np.abs(step)
        return np.maximum(step, np.minimum(self.lookahead * step, 4.0 * self.margin))

    def cover(self, x_range: tuple[float, float], y_range: tuple[float, float], extent: tuple[float, float, float],
              step: tuple[float, float] = (0.0, 0.0)) -> Box:
        """The box around the occupied extent x_range × y_range (x_range may pass the seam),
        leaving room for a particle moving by ``step`` per time step; ``extent`` is the
        domain's (x0, period, y_low, y_high)."""
        x0, period, wall_low, wall_high = extent
        if not self.enabled:
            return Box(x0, period, wall_low, wall_high)
        pad = self.margin + self.room
        (lx, hx), (ly, hy) = self._extent(x_range, step[0], pad), self._extent(y_range, step[1], pad)
        ly, hy = max(ly, wall_low), min(hy, wall_high)
        if hx - lx >= period:
            return Box(x0, period, float(ly), float(hy))
        return Box(x0 + float(np.mod(lx - x0, period)), float(hx - lx), float(ly), float(hy))

    def _extent(self, span: tuple[float, float], step: float, pad: float) -> tuple[float, float]:
        low = span[0] - pad - (self.allowance(step) if step < 0 else 0.0)
        high = span[1] + pad + (self.allowance(step) if step > 0 else 0.0)
        grow = self.slack * math.ceil((high - low) / self.slack - 1e-9) - (high - low)
        return low - 0.5 * grow, high + 0.5 * grow

    def misfits(self, extents: np.ndarray, boxes: Sequence[Box], extent: tuple[float, float, float, float],
                steps: np.ndarray) -> np.ndarray:
        """Which boxes need refitting, for all particles at once.

        extents (N, 4): occupied x_min, x_max (from each box's x0, see :func:`local_x`),
        y_min, y_max; NaN rows for particles with no node above threshold (left alone).
        steps (N, 2): each particle's displacement over the coming step. Boxes spanning the
        whole period are always re-examined."""
        if not self.enabled:
            return np.zeros(len(boxes), dtype=bool)
        _, period, wall_low, wall_high = extent
        box = np.array([[b.x0, b.width, b.y0, b.y1] for b in boxes])
        margins = np.stack([
            extents[:, 0], box[:, 1] - extents[:, 1], extents[:, 2] - box[:, 2], box[:, 3] - extents[:, 3],
        ], axis=1)
        # a box side at or beyond a wall needs no margin there
        margins[box[:, 2] <= wall_low, 2] = np.nan
        margins[box[:, 3] >= wall_high, 3] = np.nan
        ahead = np.stack([np.maximum(-steps[:, 0], 0), np.maximum(steps[:, 0], 0),
                          np.maximum(-steps[:, 1], 0), np.maximum(steps[:, 1], 0)], axis=1)
        shortest = self.margin + ahead
        longest = self.margin + 2 * self.room + self.slack + self.allowance(ahead) + self.allowance(
            ahead[:, [1, 0, 3, 2]])
        with np.errstate(invalid="ignore"):
            bad = ((margins < shortest) | (margins > longest)).any(axis=1)
        full = box[:, 1] >= period
        return (bad | full) & ~np.isnan(extents[:, 0])


def circular_extent(x: np.ndarray, period: float) -> tuple[float, float]:
    """The shortest periodic interval [a, b] (b up to a + period) holding every x: it starts
    after the widest gap between consecutive points."""
    x = np.sort(np.mod(x, period))
    gaps = np.diff(np.append(x, x[0] + period))
    widest = int(np.argmax(gaps))
    start = x[(widest + 1) % x.size]
    return float(start), float(start + period - gaps[widest])


# -- all windows of a state ---------------------------------------------------------------

class Layout:
    """All windows of a state, ordered so that windows sharing a key are contiguous.

    ``gather`` concatenates the fields into one flat vector in that order ("layout order"),
    ``scatter`` splits such a vector back into per-particle arrays (views). ``groups`` lists
    (key, particle ids, start, stop, dofs per window), each group a contiguous slice.

    node_index         the dof of every position of the flat vector
    order              particle id of every window, in layout order
    offsets, sizes     start of every window's slice (and the total), and its length
    owner              particle id of every position
    mass               lumped mass of every position's dof
    overlap_positions  positions whose dof lies in more than one window
    """

    def __init__(self, windows: Sequence[Hashable], key: Callable[[Hashable], Hashable],
                 group_dofs: Callable[[list], np.ndarray], shape: Callable[[Hashable], tuple[int, ...]],
                 lumped_mass: np.ndarray) -> None:
        """``key(window)`` groups windows; ``group_dofs(windows)`` returns the dofs (k, size)
        of k windows of one key; ``shape(window)`` the shape a window's field is viewed in."""
        self.windows = tuple(windows)
        members_of: dict = {}
        for i, w in enumerate(self.windows):
            members_of.setdefault(key(w), []).append(i)
        keys = sorted(members_of)
        self.order = np.array([i for k in keys for i in members_of[k]], dtype=int)
        self.groups = []
        self.shapes = []
        blocks = []
        start = 0
        for k in keys:
            members = np.array(members_of[k])
            dofs = group_dofs([self.windows[i] for i in members])
            size = dofs.shape[1]
            blocks.append(dofs.ravel())
            self.groups.append((k, members, start, start + size * members.size, size))
            self.shapes.append(shape(self.windows[members[0]]))
            start += size * members.size
        self.node_index = np.concatenate(blocks) if blocks else np.zeros(0, dtype=int)
        self.sizes = np.concatenate([np.full(m.size, size) for _, m, _, _, size in self.groups]).astype(int)
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        self.owner = np.repeat(self.order, self.sizes)
        self.mass = lumped_mass[self.node_index]
        self._n_dofs = lumped_mass.size

    def moved(self, windows: Sequence[Hashable], node_index: Callable[[], np.ndarray],
              mass: Callable[[], np.ndarray]) -> "Layout":
        """This layout with every window replaced by one of the same key (moved, as by the
        advection): the same groups, order and slices. ``node_index()`` and ``mass()`` give
        its positions' dofs and lumped masses, called on first use (a layout that is only
        moved on needs neither). Several times cheaper than building a layout, and the
        advection moves windows every substep."""
        moved = object.__new__(type(self))
        moved.__dict__.update({k: v for k, v in self.__dict__.items() if k not in self._PER_POSITION})
        moved.windows = tuple(windows)
        moved._pending = {"node_index": node_index, "mass": mass}
        return moved

    #: What a moved layout does not share with the layout it was moved from
    _PER_POSITION = ("node_index", "mass", "single_mass", "overlap_positions", "_parts", "_pending", "corners")

    @cached_property
    def node_index(self) -> np.ndarray:
        """The dof of every position (a moved layout's: computed on first use)."""
        return self._pending.pop("node_index")()

    @cached_property
    def mass(self) -> np.ndarray:
        """The lumped mass of every position's dof (a moved layout's: computed on first use)."""
        return self._pending.pop("mass")()

    @cached_property
    def single_mass(self) -> np.ndarray:
        """:attr:`mass` in single precision (computed on first use)."""
        return self.mass.astype(np.float32)

    def mass_like(self, values: np.ndarray) -> np.ndarray:
        """:attr:`mass` in the precision of ``values`` (float32 or float64): a product of
        mixed precisions would be computed, and returned, in double."""
        return self.single_mass if values.dtype == np.float32 else self.mass

    @cached_property
    def cells(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(slot, row, column) of every position: its window's slot in layout order and its
        row and column in the window's (ny, nx) shape (2-D shapes: the channel's windows).
        The same for every layout :meth:`moved` from this one."""
        slots, rows, columns = [], [], []
        for (_, members, start, _, size), (ny, nx) in zip(self.groups, self.shapes):
            first = int(np.searchsorted(self.offsets, start))
            slots.append(np.repeat(np.arange(first, first + members.size), size))
            rows.append(np.tile(np.repeat(np.arange(ny), nx), members.size))
            columns.append(np.tile(np.arange(nx), ny * members.size))
        if not slots:
            return (np.zeros(0, dtype=int),) * 3
        return np.concatenate(slots), np.concatenate(rows), np.concatenate(columns)

    def parts(self, positions: int) -> list[tuple[int, int, "Layout"]]:
        """The layout cut into parts of consecutive whole windows, at most ``positions``
        positions each (or one window, if larger): (first position, end position, the part as
        a layout of its own windows and groups). Small groups share a part, large ones are
        cut, so the parts are few and of about equal size. Kept for the layout's lifetime.
        A part knows nothing of the windows outside it: only window-local work (no overlaps)
        may use it."""
        cache = self.__dict__.setdefault("_parts", {})
        if positions not in cache:
            parts, pieces, filled = [], [], 0  # pieces: (group, first member, members) of the open part
            for group, (_, members, _, _, size) in enumerate(self.groups):
                first = 0
                while first < members.size:
                    room = (positions - filled) // size
                    if room <= 0 and pieces:
                        parts.append(self._part(pieces))
                        pieces, filled = [], 0
                        continue
                    taken = min(max(room, 1), members.size - first)
                    pieces.append((group, first, taken))
                    filled += taken * size
                    first += taken
            if pieces:
                parts.append(self._part(pieces))
            cache[positions] = parts
        return cache[positions]

    def _part(self, pieces: list[tuple[int, int, int]]) -> tuple[int, int, "Layout"]:
        """(first position, end position, the layout of the windows in ``pieces``: (group,
        first member, members), consecutive in layout order)."""
        part = object.__new__(type(self))
        part.__dict__.update({name: getattr(self, name) for name in self._SHARED_WITH_PARTS})
        part.windows, part._n_dofs = self.windows, self._n_dofs
        part.groups, part.shapes = [], []
        begin = end = None
        for group, first, taken in pieces:
            key, members, start, _, size = self.groups[group]
            low, high = start + first * size, start + (first + taken) * size
            begin = low if begin is None else begin
            part.groups.append((key, members[first:first + taken], low - begin, high - begin, size))
            part.shapes.append(self.shapes[group])
            end = high
        slots = slice(int(np.searchsorted(self.offsets, begin)), int(np.searchsorted(self.offsets, end)))
        part.order, part.sizes = self.order[slots], self.sizes[slots]
        part.offsets = self.offsets[slots.start:slots.stop + 1] - begin
        for name in ("node_index", "owner", "mass"):
            setattr(part, name, getattr(self, name)[begin:end])
        return begin, end, part

    @cached_property
    def overlap_positions(self) -> np.ndarray:
        """Positions whose dof lies in more than one window (computed on first use)."""
        coverage = np.bincount(self.node_index, minlength=self._n_dofs)
        return np.flatnonzero(coverage[self.node_index] > 1)

    def gather(self, fields: Sequence[np.ndarray]) -> np.ndarray:
        return np.concatenate([fields[i].ravel() for i in self.order])

    def scatter(self, flat: np.ndarray) -> list[np.ndarray]:
        """Per-particle flat views of ``flat`` (particle order)."""
        fields: list[np.ndarray] = [None] * len(self.windows)  # type: ignore[list-item]
        for slot, i in enumerate(self.order):
            fields[i] = flat[self.offsets[slot]:self.offsets[slot + 1]]
        return fields

    def group_block(self, flat: np.ndarray, group: int) -> np.ndarray:
        """The group's slice of ``flat`` as an (n_members, *shape) view."""
        _, members, start, stop, _ = self.groups[group]
        return flat[start:stop].reshape((members.size,) + self.shapes[group])

    def representative(self, group: int) -> Hashable:
        return self.windows[self.groups[group][1][0]]

    def per_slot(self, values: np.ndarray) -> np.ndarray:
        """Per-particle values (particle order) in layout order."""
        return np.asarray(values)[self.order]

    def reduce(self, ufunc: np.ufunc, values: np.ndarray) -> np.ndarray:
        """``ufunc`` reduced over every window's slice, in layout order."""
        return ufunc.reduceat(values, self.offsets[:-1])

    #: What a part (:meth:`parts`) takes from its whole layout besides windows and dofs
    _SHARED_WITH_PARTS: tuple[str, ...] = ()

    def others_squared(self, squares: np.ndarray) -> np.ndarray:
        """Σ_{j≠i} φ_j² at every position: the sum over all windows at each dof, minus the
        position's own term. Exactly zero where no other window overlaps (x + 0 − x), and,
        where windows overlap, the same sums in the same order as over the shared positions
        alone; one pass less over the positions than gathering those first (in a dense
        suspension nearly every position is shared)."""
        total = np.bincount(self.node_index, weights=squares).astype(squares.dtype, copy=False)
        others = np.take(total, self.node_index)  # 25 % faster than total[index] here
        others -= squares
        return others


class GridLayout(Layout):
    """A layout of the structured channel's rectangular windows (:class:`Window`) on its
    lattice of ``lattice`` = (ny, nx) nodes, whose sums over windows run from the windows'
    corners (:mod:`femphase.kernels`) instead of through :attr:`node_index`: a layout moved
    by the advection, at every substep under shear, then needs no dof table."""

    _SHARED_WITH_PARTS = ("lattice",)

    def __init__(self, windows: Sequence[Window], key: Callable[[Window], Hashable],
                 group_dofs: Callable[[list], np.ndarray], lumped_mass: np.ndarray,
                 lattice: tuple[int, int]) -> None:
        super().__init__(windows, key, group_dofs, lambda w: w.shape, lumped_mass)
        self.lattice = lattice

    @cached_property
    def corners(self) -> np.ndarray:
        """(windows, 4) int64: iy0, ny, ix0, nx of every window, in layout order (a moved
        layout's are given by the move)."""
        return window_corners([self.windows[i] for i in self.order])

    def others_squared(self, squares: np.ndarray) -> np.ndarray:
        """Σ_{j≠i} φ_j² at every position, bitwise as :meth:`Layout.others_squared`
        (:func:`femphase.kernels.others_squared`)."""
        from . import kernels  # numba loads only where a scene needs it

        return kernels.others_squared(squares, self.offsets, self.corners, *self.lattice)
