"""Box windows of any mesh: the dofs inside an axis-aligned box, periodic in x.

:class:`Box` is x from ``x0`` over ``width`` (mod the period) and y from ``y0`` to ``y1``, in
the mesh's length unit; :class:`BoxPolicy` is how boxes follow their fields (margins, room
for the coming motion, sizes rounded up for hysteresis). What a window is and why its system
is a principal submatrix: :mod:`femphase.domains.layout`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np

__all__ = ["Box", "BoxPolicy", "circular_extent", "local_x"]


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

    @cached_property
    def _hash(self) -> int:
        return hash((self.x0, self.width, self.y0, self.y1))

    def __hash__(self) -> int:
        # boxes key the caches and the layout's groups: looked up ~1000 times per layout,
        # and hashing the fields anew was a third of building a layout
        return self._hash


def local_x(x: np.ndarray, x0, period: float) -> np.ndarray:
    """x measured from a box's left edge x0 along +x, in [0, period)."""
    return np.mod(x - x0, period)


@dataclass(frozen=True)
class BoxPolicy:
    """How boxes follow their fields (lengths in the mesh's unit).

    =========== ============================================================================
    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      length kept between the particle and a box edge (the paper: 4 sites)
    room        extra length a refitted box leaves on each side
    slack       box sizes are rounded up to a multiple of this (hysteresis: a box fits while
                every margin is within [margin, margin + 2 room + slack + motion allowance])
    lookahead   steps of motion a refitted box leaves room for ahead of a moving particle
                (up to four margins), so that its solvers last several steps
    early       when any box must be refitted, every box within this length of a bound is
                refitted with it, so that box changes come together in fewer layouts
    enabled     False: every box is the whole domain (full-mesh mode)
    =========== ============================================================================

    Why ``early``: with windows solved all at once (:mod:`femphase.fem.blocks`) a new
    layout costs the same whether one box changed or many, and with 100 particles drifting
    one box or another outgrows its bounds at almost every substep. Refitting early cannot
    leave less than ``margin`` between a particle and its box's edge. Windows with a solver
    each refit none early (:meth:`for_spacing`).
    """

    threshold: float = 0.01
    margin: float = 4.0
    room: float = 1.0
    slack: float = 4.0
    lookahead: float = 12.0
    early: float = 0.0
    enabled: bool = True

    #: ``early`` in spacings: on examples/straight_mesh.toml under flow (400 time units of
    #: relaxation, 800 of flow at max_velocity 0.1) new layouts came at 276 of 281 refits
    #: with none, 75 at one spacing, 65 at two, 66 at three (no fewer at more: a refitted
    #: box has ``room``, one spacing, to its nearest bound); dofs did not grow
    #: (benchmarks/mesh_layouts.py).
    EARLY_SPACINGS = 2.0

    @classmethod
    def for_spacing(cls, h: float, *, threshold: float = 0.01, margin: float = 4.0,
                    enabled: bool = True, together: bool = True) -> "BoxPolicy":
        """The structured policy's margins at mesh spacing h (room h, slack ≥ 4h); with
        ``together``, boxes refitted :data:`EARLY_SPACINGS` h early and room for one step's
        motion ahead (``lookahead`` 1). Windows with a solver each want neither: every box
        refitted early is one more factorisation, and under flow the per-box LUs ran at
        0.66× the CPU without (examples/straight_mesh.toml, 400 time units of flow,
        ``numerics.solver = "direct"``: 62 and 50 against 88 and 82 ms per time unit, two
        runs each, alternating); their solvers last several steps with room for twelve.
        Windows solved all at once have no solvers to keep: with room for twelve steps the
        straight mesh's random packing at max_velocity 1 carried 1.30× the positions of room
        for one and took 1.07× its CPU under flow (400 time units, two runs each)."""
        margin = h * math.ceil(margin / h - 1e-9)
        return cls(threshold=threshold, margin=margin, room=max(h, margin / 4), slack=max(4.0 * h, margin),
                   lookahead=1.0 if together else cls.lookahead, early=cls.EARLY_SPACINGS * h if together else 0.0,
                   enabled=enabled)

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
        full = box[:, 1] >= period
        occupied = ~np.isnan(extents[:, 0])

        def outside(tighter: float) -> np.ndarray:
            with np.errstate(invalid="ignore"):
                bad = ((margins < shortest + tighter) | (margins > longest - tighter)).any(axis=1)
            return (bad | full) & occupied

        bad = outside(0.0)
        # a box over the whole period is re-examined at every refit and mostly stays: only a
        # box that must change brings the others near their bounds with it
        return outside(self.early) if self.early > 0 and (bad & ~full).any() else bad


def circular_extent(x: np.ndarray, period: float) -> tuple[float, float]:
    """The shortest periodic interval [a, b] (b up to a + period) holding every x: it starts
    after the widest gap between consecutive points."""
    x = np.sort(np.mod(x, period))
    gaps = np.diff(np.append(x, x[0] + period))
    widest = int(np.argmax(gaps))
    start = x[(widest + 1) % x.size]
    return float(start), float(start + period - gaps[widest])
