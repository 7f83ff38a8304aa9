"""The simulation state: one phase field per particle, each on its own window of a Domain."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Hashable

import numpy as np

from femphase.domains.base import Domain
from femphase.domains.layout import Layout

__all__ = ["State", "discs_state"]


@dataclass
class State:
    """Fields φ_i on windows of ``domain``, the particles' target radii, and the clock.

    fields[i] holds φ_i's values on the dofs of windows[i] (:meth:`Domain.window_dofs`, in
    that order; a flat array); φ_i is zero outside its window. time is in the model's time
    units, step counts completed steps, phase is the index of the scene phase under way and
    phase_step the steps done in it. Radii are lengths (lattice units).
    """

    domain: Domain
    windows: list[Hashable]
    fields: list[np.ndarray]
    radii: np.ndarray
    time: float = 0.0
    step: int = 0
    phase: int = 0
    phase_step: int = 0
    memory: dict = field(default_factory=dict)

    @property
    def n_particles(self) -> int:
        return len(self.fields)

    def layout(self) -> Layout:
        """The windows grouped by the domain (cached there while they do not change)."""
        return self.domain.layout(self.windows)

    def flat(self) -> tuple[Layout, np.ndarray]:
        """(layout, all fields gathered into one vector in layout order)."""
        layout = self.layout()
        return layout, layout.gather(self.fields)

    def global_field(self, i: int) -> np.ndarray:
        """Field i on every dof of the domain (zeros outside its window)."""
        out = np.zeros(self.domain.n_dofs)
        out[self.domain.window_dofs(self.windows[i])] = self.fields[i]
        return out

    def global_fields(self) -> np.ndarray:
        """(N, n_dofs) array of all fields on the whole domain (memory N × n_dofs: for
        small scenes and tests; frames work window by window)."""
        return np.stack([self.global_field(i) for i in range(self.n_particles)])

    def copy(self) -> "State":
        """A copy sharing the (immutable) domain and windows."""
        return replace(self, windows=list(self.windows), fields=[f.copy() for f in self.fields],
                       radii=self.radii.copy(), memory={k: np.copy(v) for k, v in self.memory.items()})


def discs_state(domain: Domain, centres: np.ndarray, radii: np.ndarray, initial_radii: np.ndarray,
                interface_width: float, policy) -> State:
    """Discs of radius ``initial_radii`` at ``centres`` (N, 2), with target radii ``radii``:
    the profile (1 + tanh((r0 − d)/λ))/2, each on the window that covers it."""
    windows, fields = [], []
    for centre, r0 in zip(np.asarray(centres, dtype=float), np.broadcast_to(initial_radii, len(centres))):
        # where the profile crosses the policy's threshold
        reach = r0 + interface_width * np.arctanh(1.0 - 2.0 * policy.threshold)
        window = domain.disc_window(tuple(centre), reach, policy)
        windows.append(window)
        fields.append(domain.disc_field(window, tuple(centre), r0, interface_width))
    return State(domain, windows, fields, np.asarray(radii, dtype=float).copy())
