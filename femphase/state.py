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

    def __post_init__(self) -> None:
        counts = {"windows": len(self.windows), "fields": len(self.fields), "radii": np.size(self.radii)}
        if len(set(counts.values())) > 1:
            raise ValueError("a State needs one window, field and radius per particle; got "
                             + ", ".join(f"{n} {name}" for name, n in counts.items()))
        radii = np.asarray(self.radii, dtype=float)
        if radii.size and not (np.all(np.isfinite(radii)) and np.all(radii > 0)):
            raise ValueError(f"State radii must be finite target radii > 0 (lattice units); got {radii.tolist()}")
        for i, (window, values) in enumerate(zip(self.windows, self.fields)):
            size = self.domain.window_dofs(window).size
            if np.size(values) != size:
                raise ValueError(f"State field {i} has {np.size(values)} values; its window {window!r} holds {size} "
                                 "dofs (fields[i] lists φ_i on the dofs of windows[i], Domain.window_dofs)")
        if min(self.phase, self.phase_step, self.step) < 0:
            raise ValueError(f"State phase, phase_step and step count from 0; got {self.phase}, {self.phase_step}, "
                             f"{self.step}")

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
    """Discs of radius ``initial_radii`` at ``centres`` (N, 2), with target radii ``radii``
    (lengths in lattice units; each one value or N): the profile (1 + tanh((r0 − d)/λ))/2,
    λ = ``interface_width``, each on the window that covers it. ValueError for radii that
    are not > 0 or do not match the centres, or a centre outside the domain's walls."""
    centres = np.asarray(centres, dtype=float).reshape(-1, 2)
    low, high = domain.y_range
    for name, values in (("radii", radii), ("initial_radii", initial_radii)):
        values = np.asarray(values, dtype=float)
        if values.size not in (1, len(centres)) or not (np.all(np.isfinite(values)) and np.all(values > 0)):
            raise ValueError(f"discs_state {name} must be one length > 0 or one per centre ({len(centres)}); "
                             f"got {values.tolist()}")
    outside = np.flatnonzero((centres[:, 1] < low) | (centres[:, 1] > high) | ~np.isfinite(centres).all(axis=1))
    if outside.size:
        raise ValueError(f"discs_state centre {centres[outside[0]].tolist()} lies outside the domain's walls "
                         f"(y from {low:g} to {high:g})")
    windows, fields = [], []
    for centre, r0 in zip(centres, np.broadcast_to(initial_radii, len(centres))):
        # where the profile crosses the policy's threshold t: arctanh(1 − 2t) = ½ ln((1 − t)/t),
        # finite for every t > 0 (1 − 2t is 1, and its arctanh infinite, for t below 1.1e-16)
        reach = r0 + interface_width * 0.5 * np.log((1.0 - policy.threshold) / policy.threshold)
        window = domain.disc_window(tuple(centre), reach, policy)
        windows.append(window)
        fields.append(domain.disc_field(window, tuple(centre), r0, interface_width))
    return State(domain, windows, fields, np.broadcast_to(np.asarray(radii, dtype=float), len(centres)).copy())
