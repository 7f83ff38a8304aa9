"""Initial particle positions: a hexagonal lattice, or random non-overlapping discs.

Lengths in lattice units; x is periodic with the domain's period, y runs between the walls.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from femphase.errors import SceneError

__all__ = ["clear_of_discs", "hexagonal_centres", "random_centres", "random_centres_inside"]


def hexagonal_centres(n: int, length: float, width: float, per_row: int | None = None) -> np.ndarray:
    """A hexagonal lattice with rows along x filling the channel: per_row × rows = n.

    Without per_row, the row length is the one closest to an ideal lattice of n sites on
    the channel's area. Rows are ``width/rows`` apart, alternate rows offset by half a
    spacing (the paper's Fig. 2: 5 per row, 20 rows in 70 × 240).
    """
    if per_row is None:
        spacing = math.sqrt(2.0 * length * width / (math.sqrt(3.0) * n))
        per_row = max(1, round(length / spacing))
    if n % per_row:
        raise SceneError("particles.N", n, f"a multiple of per_row = {per_row} for the hexagonal layout")
    rows = n // per_row
    dx, dy = length / per_row, width / rows
    i, j = np.meshgrid(np.arange(per_row), np.arange(rows))
    x = ((i + 0.25 + 0.5 * (j % 2)) * dx) % length
    y = (j + 0.5) * dy
    return np.stack([x.ravel(), y.ravel()], axis=1)


def clear_of_discs(centres: np.ndarray, candidate: np.ndarray, period: float, radius: float) -> bool:
    """Whether a disc of ``radius`` at ``candidate`` overlaps none of the discs at ``centres``
    (the same radius; distances by the minimum image over the period in x)."""
    dx = (centres[:, 0] - candidate[0] + 0.5 * period) % period - 0.5 * period
    return bool(np.all(dx**2 + (centres[:, 1] - candidate[1]) ** 2 >= (2 * radius) ** 2))


def random_centres(n: int, length: float, width: float, radius: float, seed: int, attempts: int = 200_000) -> np.ndarray:
    """Uniformly random centres of non-overlapping discs of ``radius`` inside the channel."""
    rng = np.random.default_rng(seed)
    centres = np.empty((0, 2))
    for _ in range(attempts):
        candidate = np.array([rng.uniform(0, length), rng.uniform(radius, width - radius)])
        if clear_of_discs(centres, candidate, length, radius):
            centres = np.vstack([centres, candidate])
            if len(centres) == n:
                return centres
    raise _too_few(n, len(centres), radius, attempts)


def random_centres_inside(
    n: int, radius: float, seed: int, *, x0: float, period: float, y_range: tuple[float, float],
    inside: Callable[[np.ndarray, np.ndarray], np.ndarray], walls: np.ndarray, attempts: int = 200_000,
) -> np.ndarray:
    """Uniformly random centres of non-overlapping discs of ``radius`` in any domain: each
    centre ``inside`` it and at least ``radius`` from every wall point (2, n_points)."""
    rng = np.random.default_rng(seed)
    low, high = y_range
    centres = np.empty((0, 2))
    batch = 256
    for _ in range(0, attempts, batch):
        candidates = np.stack([x0 + rng.uniform(0, period, batch), rng.uniform(low, high, batch)], 1)
        dx = np.mod(walls[0][None] - candidates[:, :1] + 0.5 * period, period) - 0.5 * period
        clear = np.hypot(dx, walls[1][None] - candidates[:, 1:]).min(axis=1) >= radius
        candidates = candidates[clear & inside(candidates[:, 0], candidates[:, 1])]
        for candidate in candidates:
            if clear_of_discs(centres, candidate, period, radius):
                centres = np.vstack([centres, candidate])
                if len(centres) == n:
                    return centres
    raise _too_few(n, len(centres), radius, attempts)


def _too_few(n: int, placed: int, radius: float, attempts: int) -> SceneError:
    return SceneError(
        "particles.N", n,
        f"only {placed} non-overlapping initial discs of radius {radius:g} fit after {attempts} tries; "
        "use fewer particles or a smaller particles.initial_radius",
    )
