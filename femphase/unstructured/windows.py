"""Windows on a meshed channel: each field lives on the dofs inside a box around its particle.

The structured core's windows are rectangular node blocks; on an unstructured mesh a window
is the set of dofs inside an axis-aligned :class:`Box` (periodic in x), fitted exactly as
:class:`femphase.windows.WindowPolicy` fits blocks: around the nodes where φ > threshold, with
``margin`` length units of zeros on every side that is not beyond a wall, grown when a margin
runs short, shrunk when one is far too long, wrapped across the periodic seam, spanning the
whole period when the particle is longer than it. Boxes may reach into holes of the mesh
(an obstacle, the space outside a constricted wall): only dofs inside count.

Moving particles: a box must hold its particle after the coming advection step, so the
margin ahead of a particle moving at velocity U is ``margin + |U| dt``, and a refitted box
leaves room for ``lookahead`` steps of motion ahead of the particle (up to four margins):
the window, its matrices and their factorisations then last several steps.

Outside its window a field is zero, so a window's linear system is the principal submatrix
of the global system on its dofs (zero Dirichlet data on the artificial edges of the box,
natural Neumann at the walls), exactly as on the structured mesh.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .domain import MeshDomain


@dataclass(frozen=True)
class Box:
    """x from ``x0`` over ``width`` (mod the period; ``width == period``: the whole period),
    y from ``y0`` to ``y1`` (length units)."""

    x0: float
    width: float
    y0: float
    y1: float

    def nodes(self, domain: MeshDomain) -> np.ndarray:
        """The dofs inside the box, sorted."""
        x, y = domain.coordinates
        inside = (local_x(x, self.x0, domain.period) <= self.width) & (y >= self.y0) & (y <= self.y1)
        return np.flatnonzero(inside)


def local_x(x: np.ndarray, x0, period: float) -> np.ndarray:
    """x measured from a box's left edge x0 along +x, in [0, period)."""
    return np.mod(x - x0, period)


def full_box(domain: MeshDomain) -> Box:
    low, high = domain.y_range
    return Box(domain.x0, domain.period, low, high)


@dataclass(frozen=True)
class MeshWindowPolicy:
    """How boxes follow their fields (lengths in the mesh's unit).

    threshold   φ above which a node belongs to the particle (the paper: 0.01)
    margin      length kept between the particle and a box edge (the paper: 4 sites)
    room        extra length a refitted box leaves on each side
    slack       box sizes are rounded up to a multiple of this (hysteresis: a box fits while
                every margin is within [margin, margin + 2 room + slack + motion allowance])
    lookahead   steps of motion a refitted box leaves room for ahead of a moving particle
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
                    enabled: bool = True) -> "MeshWindowPolicy":
        """The structured policy's margins at mesh spacing h (room h, slack ≥ 4h)."""
        margin = h * math.ceil(margin / h - 1e-9)
        return cls(threshold=threshold, margin=margin, room=max(h, margin / 4),
                   slack=max(4.0 * h, margin), enabled=enabled)

    def allowance(self, step: np.ndarray) -> np.ndarray:
        """Room ahead of a particle moving by ``step`` per time step (any shape)."""
        step = np.abs(step)
        return np.maximum(step, np.minimum(self.lookahead * step, 4.0 * self.margin))

    def cover(self, domain: MeshDomain, x_range: tuple[float, float], y_range: tuple[float, float],
              step: tuple[float, float] = (0.0, 0.0)) -> Box:
        """The box around the occupied extent x_range × y_range (x_range may pass the seam:
        x1 > x0 + period), leaving room for a particle moving by ``step`` per time step."""
        if not self.enabled:
            return full_box(domain)
        pad = self.margin + self.room
        (lx, hx), (ly, hy) = self._extent(x_range, step[0], pad), self._extent(y_range, step[1], pad)
        wall_low, wall_high = domain.y_range
        ly, hy = max(ly, wall_low), min(hy, wall_high)
        if hx - lx >= domain.period:
            return Box(domain.x0, domain.period, float(ly), float(hy))
        return Box(domain.x0 + float(np.mod(lx - domain.x0, domain.period)), float(hx - lx), float(ly), float(hy))

    def _extent(self, span: tuple[float, float], step: float, pad: float) -> tuple[float, float]:
        low = span[0] - pad - (self.allowance(step) if step < 0 else 0.0)
        high = span[1] + pad + (self.allowance(step) if step > 0 else 0.0)
        grow = self.slack * math.ceil((high - low) / self.slack - 1e-9) - (high - low)
        return low - 0.5 * grow, high + 0.5 * grow

    def misfits(self, extents: np.ndarray, boxes: list[Box], domain: MeshDomain,
                steps: np.ndarray) -> np.ndarray:
        """Which boxes need refitting, for all particles at once.

        extents (N, 4): occupied x_min, x_max (measured from each box's x0, see
        :func:`local_x`), y_min, y_max; NaN rows for particles with no node above threshold
        (left alone). steps (N, 2): each particle's displacement over the coming step.
        Boxes spanning the whole period are always re-examined.
        """
        if not self.enabled:
            return np.zeros(len(boxes), dtype=bool)
        box = np.array([[b.x0, b.width, b.y0, b.y1] for b in boxes])
        wall_low, wall_high = domain.y_range
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
        full = box[:, 1] >= domain.period
        return (bad | full) & ~np.isnan(extents[:, 0])


def circular_extent(x: np.ndarray, period: float) -> tuple[float, float]:
    """The shortest periodic interval [a, b] (b may exceed a + … up to a + period) holding
    every x: it starts after the widest gap between consecutive points."""
    x = np.sort(np.mod(x, period))
    gaps = np.diff(np.append(x, x[0] + period))
    widest = int(np.argmax(gaps))
    start = x[(widest + 1) % x.size]
    return float(start), float(start + period - gaps[widest])


class MeshLayout:
    """All windows' dofs concatenated, particle by particle.

    ``node_index`` holds the dofs, ``offsets`` the start of each particle's slice (and the
    total at the end), ``owner`` the particle of every position, ``mass`` the lumped mass of
    every position's dof and ``overlap_positions`` the positions whose dof lies in more than
    one window.
    """

    def __init__(self, nodes: list[np.ndarray], lumped_mass: np.ndarray) -> None:
        self.sizes = np.array([n.size for n in nodes])
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes)])
        self.node_index = np.concatenate(nodes)
        self.owner = np.repeat(np.arange(len(nodes)), self.sizes)
        self.mass = lumped_mass[self.node_index]
        coverage = np.bincount(self.node_index, minlength=lumped_mass.size)
        self.overlap_positions = np.flatnonzero(coverage[self.node_index] > 1)

    def split(self, flat: np.ndarray) -> list[np.ndarray]:
        return np.split(flat, self.offsets[1:-1])

    def reduce(self, ufunc: np.ufunc, values: np.ndarray) -> np.ndarray:
        """``ufunc`` reduced over every particle's slice (e.g. np.add, np.minimum)."""
        return ufunc.reduceat(values, self.offsets[:-1])
