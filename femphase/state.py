"""The simulation state: one phase field per particle, each on its own window."""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from .mesh import ChannelGrid
from .model import interface_profile
from .windows import Window, WindowPolicy


@dataclass
class State:
    """Fields φ_i on windows, the particles' target radii, and the clock.

    fields[i] is an (windows[i].ny, windows[i].nx) array of nodal values; the field is zero
    outside its window. time is in the model's time units, step counts completed steps,
    phase is the index of the scene phase under way and phase_step the steps done in it.
    """

    grid: ChannelGrid
    windows: list[Window]
    fields: list[np.ndarray]
    radii: np.ndarray
    time: float = 0.0
    step: int = 0
    phase: int = 0
    phase_step: int = 0

    @property
    def n_particles(self) -> int:
        return len(self.fields)

    def global_field(self, i: int) -> np.ndarray:
        """Field i on every node of the channel, in grid order (zeros outside its window)."""
        out = np.zeros(self.grid.n_nodes)
        out[self.windows[i].node_indices(self.grid)] = self.fields[i].ravel()
        return out

    def global_fields(self) -> np.ndarray:
        """(N, n_nodes) array of all fields on the whole channel."""
        return np.stack([self.global_field(i) for i in range(self.n_particles)])

    def copy(self) -> "State":
        return copy.deepcopy(self)


def disc_field(
    grid: ChannelGrid, window: Window, centre: tuple[float, float], radius: float, width: float
) -> np.ndarray:
    """The equilibrium profile (1 + tanh((radius − d)/λ))/2 of a disc, on ``window``.

    d is the distance to ``centre`` with the minimum image in x (periodic).
    """
    x = window.columns(grid) * grid.h
    y = window.rows() * grid.h
    dx = (x - centre[0] + 0.5 * grid.length) % grid.length - 0.5 * grid.length
    dy = y - centre[1]
    distance = np.hypot(dx[None, :], dy[:, None])
    return interface_profile(radius - distance, width)


def discs_state(
    grid: ChannelGrid,
    centres: np.ndarray,
    radii: np.ndarray,
    initial_radii: np.ndarray,
    interface_width: float,
    policy: WindowPolicy,
) -> State:
    """A state of discs of radius initial_radii at centres, with target radii ``radii``."""
    windows, fields = [], []
    for (cx, cy), r0 in zip(centres, initial_radii):
        # the box where the profile exceeds the threshold, in nodes
        reach = r0 + interface_width * np.arctanh(1.0 - 2.0 * policy.threshold)
        rows = (max(0, int(np.floor((cy - reach) / grid.h))), min(grid.ny - 1, int(np.ceil((cy + reach) / grid.h))))
        cols = (int(np.floor((cx - reach) / grid.h)), int(np.ceil((cx + reach) / grid.h)))
        window = policy.cover(rows, cols, grid)
        windows.append(window)
        fields.append(disc_field(grid, window, (cx, cy), r0, interface_width))
    return State(grid=grid, windows=windows, fields=fields, radii=np.asarray(radii, dtype=float))
