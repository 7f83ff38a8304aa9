"""All windows of a state in one flat vector (:class:`Layout`).

Each field is computed only on a window: a set of dofs that covers its particle. As in the
paper's supplement, a window covers the nodes where φ > threshold plus a margin (4 lattice
units by default) on every side; it grows when the margin runs short, shrinks when it is
far too long, follows the particle, wraps periodically in x and ends at the walls. Outside
its window a field is zero, so a window's linear system is the principal submatrix of the
full-domain system on the window's dofs (homogeneous Dirichlet data on the window's
artificial edges, natural Neumann on the walls).

A window is a hashable description that its :class:`~femphase.domains.base.Domain` turns
into dofs: a rectangular block of the structured channel's lattice
(:class:`femphase.domains.grid.windows.Window`), the dofs of a mesh within a reach of its
particle (:class:`femphase.domains.mesh.shapes.Shape`) or inside a box
(:class:`femphase.domains.mesh.boxes.Box`). Windows with one key share one system matrix.
:class:`Layout` concatenates all windows' fields into one flat vector, grouped by key.
"""

from __future__ import annotations

from functools import cached_property
from typing import Callable, Hashable, Sequence

import numpy as np

__all__ = ["Layout", "largest_difference"]


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

    @property
    def nbytes(self) -> int:
        """Bytes of the per-position and per-window arrays computed so far."""
        return sum(int(value.nbytes) for value in self.__dict__.values() if isinstance(value, np.ndarray))

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
        """The group's slice of ``flat`` as an ``(n_members, *shape)`` view."""
        _, members, start, stop, _ = self.groups[group]
        return flat[start:stop].reshape((members.size,) + self.shapes[group])

    def representative(self, group: int) -> Hashable:
        return self.windows[self.groups[group][1][0]]

    @cached_property
    def slots(self) -> np.ndarray:
        """The slot of every particle (particle order): the inverse of :attr:`order`."""
        slots = np.empty(len(self.order), dtype=np.int64)
        slots[self.order] = np.arange(len(self.order))
        return slots

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
        suspension nearly every position is shared). Compiled
        (:func:`femphase.fem.kernels.others_squared`), bitwise numpy's
        ``bincount(node_index, squares)[node_index] − squares`` rounded to φ's precision."""
        from femphase.fem import kernels  # numba loads only where a scene needs it

        return kernels.others_squared(squares, self.node_index, self._n_dofs)


def largest_difference(first: np.ndarray, first_layout: Layout, second: np.ndarray, second_layout: Layout) -> float:
    """The largest absolute difference of φ and ψ over every particle and dof, φ = ``first``
    on ``first_layout`` and ψ = ``second`` on ``second_layout`` (each zero outside its
    windows): position by position where the two layouts hold the same windows, else
    matched by (particle, dof)."""
    if not first.size and not second.size:
        return 0.0
    if first_layout.windows == second_layout.windows:
        return float(np.max(np.abs(first - second)))
    n_dofs = int(max(first_layout.node_index.max(initial=0), second_layout.node_index.max(initial=0))) + 1
    keys = np.concatenate([first_layout.owner * n_dofs + first_layout.node_index,
                           second_layout.owner * n_dofs + second_layout.node_index])
    _, where = np.unique(keys, return_inverse=True)
    signed = np.concatenate([np.asarray(first, dtype=float), -np.asarray(second, dtype=float)])
    return float(np.max(np.abs(np.bincount(where, weights=signed))))
