"""Per-particle windows: each field lives on a rectangular block of the channel's nodes.

As in the paper's supplement, a field is only computed on a window that covers it: the
nodes where φ > threshold, plus a margin (4 lattice units by default) on every side. The
window grows when the margin runs short, shrinks when it is far too long, is not forced to
be square, follows the particle, wraps periodically in x and is clipped at the walls.

Outside its window a field is zero. A window's linear system is therefore the principal
submatrix of the full-mesh system on the window's nodes (homogeneous Dirichlet data on the
window's artificial edges, natural Neumann on the walls). On the structured mesh that
submatrix depends only on the window's :meth:`Window.key`, so windows of the same shape
share one matrix, one factorisation and one multi-right-hand-side solve.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .mesh import ChannelGrid


@dataclass(frozen=True)
class Window:
    """Rows iy0 … iy0+ny−1 and columns ix0 … ix0+nx−1 (mod grid.nx) of the node lattice.

    A window with nx == grid.nx spans the whole periodic width (then ix0 = 0).
    """

    iy0: int
    ny: int
    ix0: int
    nx: int

    def rows(self) -> np.ndarray:
        return np.arange(self.iy0, self.iy0 + self.ny)

    def columns(self, grid: ChannelGrid) -> np.ndarray:
        return (self.ix0 + np.arange(self.nx)) % grid.nx

    def node_indices(self, grid: ChannelGrid) -> np.ndarray:
        """Global dofs of the window's nodes, row by row (x fastest)."""
        return (self.rows()[:, None] * grid.nx + self.columns(grid)[None, :]).ravel()

    def key(self, grid: ChannelGrid, alternating: bool) -> tuple:
        """Everything the window's submatrix depends on: shape, walls touched, periodicity,
        and (for the alternating diagonal pattern only) the chequerboard parity."""
        parity = (self.ix0 + self.iy0) % 2 if alternating else 0
        return (
            self.ny,
            self.nx,
            self.iy0 == 0,
            self.iy0 + self.ny == grid.ny,
            self.nx == grid.nx,
            parity,
        )


def full_window(grid: ChannelGrid) -> Window:
    """The window that is the whole mesh (full-mesh mode)."""
    return Window(0, grid.ny, 0, grid.nx)


@dataclass(frozen=True)
class WindowPolicy:
    """How windows follow their fields (all lengths in nodes of the grid).

    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      nodes kept between the particle and a window edge (the paper: 4 sites)
    room        extra nodes a new window leaves on each side, so it need not move every step
    quantum     window sizes are rounded up to a multiple of this, so that few distinct
                shapes (and factorisations) exist
    enabled     False: every window is the whole mesh (full-mesh mode)
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
        return cls(
            threshold=threshold,
            margin=margin_nodes,
            room=max(1, math.ceil(margin_nodes / 4)),
            quantum=max(4, 2 * math.ceil(1.0 / h)),
            enabled=enabled,
        )

    def cover(self, rows: tuple[int, int], cols: tuple[int, int], grid: ChannelGrid) -> Window:
        """A window around the occupied node box rows × cols (inclusive, cols may exceed nx)."""
        if not self.enabled:
            return full_window(grid)
        pad = self.margin + self.room
        ny = _round_up(rows[1] - rows[0] + 1 + 2 * pad, self.quantum)
        nx = _round_up(cols[1] - cols[0] + 1 + 2 * pad, self.quantum)
        iy0 = rows[0] - (ny - (rows[1] - rows[0] + 1)) // 2
        # clip at the walls: the window ends there, it does not slide inward
        top = min(iy0 + ny, grid.ny)
        iy0 = max(iy0, 0)
        ny = top - iy0
        if nx >= grid.nx:
            return Window(int(iy0), int(ny), 0, int(grid.nx))
        ix0 = (cols[0] - (nx - (cols[1] - cols[0] + 1)) // 2) % grid.nx
        return Window(int(iy0), int(ny), int(ix0), int(nx))

    def misfits(self, block: np.ndarray, windows: list[Window], grid: ChannelGrid) -> np.ndarray:
        """For fields block (n, ny, nx) on windows of one shape: which need another window.

        A window fits while every margin not at a wall lies within
        [margin, margin + 2·room + quantum]; full-width windows are always re-examined.
        """
        if not self.enabled:
            return np.zeros(len(windows), dtype=bool)
        occupied = block > self.threshold
        rows, cols = occupied.any(axis=2), occupied.any(axis=1)
        empty = ~rows.any(axis=1)
        ny, nx = block.shape[1:]
        bottom = np.argmax(rows, axis=1).astype(float)
        top = np.argmax(rows[:, ::-1], axis=1).astype(float)
        left = np.argmax(cols, axis=1)
        right = np.argmax(cols[:, ::-1], axis=1)
        iy0 = np.array([w.iy0 for w in windows])
        bottom[iy0 == 0] = np.nan
        top[iy0 + ny == grid.ny] = np.nan
        margins = np.stack([left, right, bottom, top], axis=1)
        longest = self.margin + 2 * self.room + self.quantum
        with np.errstate(invalid="ignore"):
            bad = ((margins < self.margin) | (margins > longest)).any(axis=1)
        return (bad | (nx == grid.nx)) & ~empty

    def fit(self, phi: np.ndarray, window: Window, grid: ChannelGrid) -> Window:
        """The window ``phi`` (on ``window``) should live on next: ``window`` itself unless
        :meth:`misfits` says otherwise."""
        if not self.misfits(phi[None], [window], grid)[0]:
            return window
        occupied = phi > self.threshold
        row_hits = np.flatnonzero(occupied.any(axis=1))
        rows = (window.iy0 + row_hits[0], window.iy0 + row_hits[-1])
        col_occupied = occupied.any(axis=0)
        if window.nx == grid.nx:
            c0, c1 = _circular_extent(col_occupied)
            if c1 - c0 + 1 + 2 * (self.margin + self.room) + self.quantum > grid.nx:
                return window
            return self.cover(rows, (c0, c1), grid)
        col_hits = np.flatnonzero(col_occupied)
        return self.cover(rows, (window.ix0 + col_hits[0], window.ix0 + col_hits[-1]), grid)


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


def pad_window(phi: np.ndarray, window: Window, grid: ChannelGrid, width: int) -> np.ndarray:
    """phi (..., ny, nx) with ``width`` extra nodes on every side: mirrored at a wall (the
    Neumann condition), periodic across the seam of a full-width window, zero beyond a
    window's artificial edge (the field is zero there by definition). Leading axes stack
    fields on windows of the same key."""
    ny, nx = phi.shape[-2:]
    # filled slice by slice: np.pad's generality costs ~0.3 ms a call, and this runs for
    # every window at every frame
    out = np.zeros(phi.shape[:-2] + (ny + 2 * width, nx + 2 * width), dtype=phi.dtype)
    out[..., width:width + ny, width:width + nx] = phi
    if window.iy0 == 0:  # reflected without repeating the wall row, as np.pad's "reflect"
        out[..., :width, width:width + nx] = phi[..., width:0:-1, :]
    if window.iy0 + window.ny == grid.ny:
        out[..., width + ny:, width:width + nx] = phi[..., -2:-2 - width:-1, :]
    if window.nx == grid.nx:
        out[..., :width] = out[..., nx:nx + width]
        out[..., width + nx:] = out[..., width:2 * width]
    return out


def transfer(phi: np.ndarray, old: Window, new: Window, grid: ChannelGrid) -> np.ndarray:
    """The field ``phi`` (on ``old``) on the nodes of ``new``; zero where ``old`` had none."""
    out = np.zeros((new.ny, new.nx), dtype=phi.dtype)
    row_lo, row_hi = max(old.iy0, new.iy0), min(old.iy0 + old.ny, new.iy0 + new.ny)
    if row_lo >= row_hi:
        return out
    local_old = (new.columns(grid) - old.ix0) % grid.nx
    keep = local_old < old.nx
    out[row_lo - new.iy0:row_hi - new.iy0, keep] = phi[row_lo - old.iy0:row_hi - old.iy0][:, local_old[keep]]
    return out


class Layout:
    """All windows of a state, ordered so that windows sharing a key are contiguous.

    ``gather`` concatenates the fields into one flat vector in that order, ``scatter`` splits
    such a vector back into per-particle arrays. ``groups`` lists (key, particle ids,
    start, stop, dofs per window), each group a contiguous slice of the flat vector.
    """

    def __init__(self, windows: list[Window], grid: ChannelGrid, alternating: bool) -> None:
        self.windows = tuple(windows)
        keys = [w.key(grid, alternating) for w in windows]
        members_of: dict[tuple, list[int]] = {}
        for i, key in enumerate(keys):
            members_of.setdefault(key, []).append(i)
        self.order = np.array([i for key in sorted(members_of) for i in members_of[key]], dtype=int)
        sizes = np.array([windows[i].ny * windows[i].nx for i in self.order])
        self.offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.groups = []
        blocks = []
        start = 0
        for key in sorted(members_of):
            members = np.array(members_of[key])
            w = windows[members[0]]
            iy0 = np.array([windows[i].iy0 for i in members])
            ix0 = np.array([windows[i].ix0 for i in members])
            rows = iy0[:, None, None] + np.arange(w.ny)[None, :, None]
            cols = (ix0[:, None, None] + np.arange(w.nx)[None, None, :]) % grid.nx
            blocks.append((rows * grid.nx + cols).ravel())
            stop = start + w.ny * w.nx * members.size
            self.groups.append((key, members, start, stop, w.ny * w.nx))
            start = stop
        self.node_index = np.concatenate(blocks)
        self.sizes = np.diff(self.offsets)
        coverage = np.bincount(self.node_index, minlength=grid.n_nodes)
        #: positions in the flat vector whose node is covered by more than one window
        self.overlap_positions = np.flatnonzero(coverage[self.node_index] > 1)

    def gather(self, fields: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([fields[i].ravel() for i in self.order])

    def scatter(self, flat: np.ndarray) -> list[np.ndarray]:
        fields: list[np.ndarray] = [None] * len(self.windows)  # type: ignore[list-item]
        for key, members, start, stop, size in self.groups:
            w = self.windows[members[0]]
            block = flat[start:stop].reshape(members.size, w.ny, w.nx)
            for i, values in zip(members, block):
                fields[i] = values
        return fields

    def group_block(self, flat: np.ndarray, group: int) -> np.ndarray:
        """The group's slice of ``flat`` as an (n_members, ny, nx) view."""
        _, members, start, stop, _ = self.groups[group]
        w = self.windows[members[0]]
        return flat[start:stop].reshape(members.size, w.ny, w.nx)

    def representative(self, group: int) -> Window:
        return self.windows[self.groups[group][1][0]]
