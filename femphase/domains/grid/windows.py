"""Rectangular windows of the structured channel's node lattice, and their layout.

:class:`Window` is a block of lattice nodes (first row and column, height and width; it
wraps in x across the periodic seam and ends at the walls). Its submatrix depends only on
:meth:`Window.key`, so windows of one shape share one matrix, one solver and one
multi-right-hand-side solve (the structured fast path). :class:`WindowPolicy` is how windows
follow their fields (threshold, margin, sizes rounded to a quantum, hysteresis);
:class:`GridLayout` is a :class:`~femphase.domains.layout.Layout` that also knows every
window's corners, from which the compiled loops of :mod:`femphase.domains.grid.kernels` run.
What a window is and why its system is a principal submatrix: :mod:`femphase.domains.layout`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Hashable, Sequence

import numpy as np

from femphase.domains.layout import Layout

__all__ = ["GridLayout", "Window", "WindowPolicy", "pad_window", "transfer", "window_corners"]


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
        # transforms them in one call (femphase.domains.grid.advection.row_runs)
        return (self.nx, self.ny, self.iy0 == 0, self.iy0 + self.ny == lattice_ny, self.nx == lattice_nx, parity)


@dataclass(frozen=True)
class WindowPolicy:
    """How rectangular windows follow their fields (all lengths in nodes of the lattice).

    =========== ============================================================================
    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      nodes kept between the particle and a window edge (the paper: 4 sites)
    room        extra nodes a new window leaves on each side, so it need not move every step
    quantum     window sizes are rounded up to a multiple of this, so that few distinct
                shapes (and solvers) exist
    enabled     False: every window is the whole channel (full-mesh mode)
    =========== ============================================================================
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
        window where it nowhere does (:func:`femphase.domains.grid.kernels.occupied_boxes`, one compiled
        scan of all windows)."""
        from femphase.domains.grid import (
            kernels,  # numba loads only where a scene needs it
        )

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
        for numpy's boolean reductions group by group (docs/decisions/0013-compiled-window-loops.md)."""
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
        from femphase.domains.grid import kernels

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


class GridLayout(Layout):
    """A layout of the structured channel's rectangular windows (:class:`Window`) on its
    lattice of ``lattice`` = (ny, nx) nodes, whose sums over windows run from the windows'
    corners (:mod:`femphase.domains.grid.kernels`) instead of through :attr:`node_index`: a layout moved
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
        (:func:`femphase.domains.grid.kernels.others_squared`)."""
        from femphase.domains.grid import (
            kernels,  # numba loads only where a scene needs it
        )

        return kernels.others_squared(squares, self.offsets, self.corners, *self.lattice)
