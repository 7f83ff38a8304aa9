"""The state on a meshed channel: one phase field per particle on the dofs of its window."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..model import interface_profile
from .domain import MeshDomain
from .windows import Box, MeshWindowPolicy


@dataclass
class MeshState:
    """Fields φ_i on windows of a :class:`MeshDomain`, the particles' target radii, the clock.

    ``nodes[i]`` are the sorted dofs of window ``boxes[i]`` and ``fields[i]`` the field's
    values there (zero elsewhere). time is in the model's time units, step counts completed
    steps, phase / phase_step locate the run in a scene's phases (as :class:`femphase.state.State`).
    Node arrays are never modified in place, so copies share them.
    """

    domain: MeshDomain
    boxes: list[Box]
    nodes: list[np.ndarray]
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
        """Field i on every dof (zeros outside its window)."""
        out = np.zeros(self.domain.n_dofs)
        out[self.nodes[i]] = self.fields[i]
        return out

    def global_fields(self) -> np.ndarray:
        """(N, n_dofs) array of all fields on the whole domain."""
        return np.stack([self.global_field(i) for i in range(self.n_particles)])

    def copy(self) -> "MeshState":
        """A copy sharing the (immutable) domain and node arrays."""
        return replace(self, boxes=list(self.boxes), nodes=list(self.nodes),
                       fields=[f.copy() for f in self.fields], radii=self.radii.copy())


def disc_values(domain: MeshDomain, nodes: np.ndarray, centre, radius: float, width: float) -> np.ndarray:
    """The equilibrium profile (1 + tanh((radius − d)/λ))/2 of a disc at ``nodes``; d is the
    distance to ``centre`` with the minimum image in x."""
    x, y = domain.coordinates[:, nodes]
    period = domain.period
    dx = np.mod(x - centre[0] + 0.5 * period, period) - 0.5 * period
    return interface_profile(radius - np.hypot(dx, y - centre[1]), width)


def mesh_discs_state(
    domain: MeshDomain,
    centres: np.ndarray,
    radii: np.ndarray,
    initial_radii: np.ndarray,
    interface_width: float,
    policy: MeshWindowPolicy,
) -> MeshState:
    """Discs of radius initial_radii at centres (N, 2), with target radii ``radii``."""
    boxes, nodes, fields = [], [], []
    for (cx, cy), r0 in zip(np.asarray(centres, float), np.broadcast_to(initial_radii, len(centres))):
        reach = r0 + interface_width * np.arctanh(1.0 - 2.0 * policy.threshold)
        box = policy.cover(domain, (cx - reach, cx + reach), (cy - reach, cy + reach))
        inside = box.nodes(domain)
        boxes.append(box)
        nodes.append(inside)
        fields.append(disc_values(domain, inside, (cx, cy), r0, interface_width))
    return MeshState(domain, boxes, nodes, fields, np.asarray(radii, dtype=float).copy())


def save_mesh_checkpoint(path: str | Path, state: MeshState, observers: dict[str, np.ndarray] | None = None) -> None:
    """Write the state (not the domain: the scene names its mesh) atomically, with the
    observers' running state (see :func:`femphase.io.save_checkpoint`)."""
    path = Path(path)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(
        tmp,
        boxes=np.array([[b.x0, b.width, b.y0, b.y1] for b in state.boxes]).reshape(-1, 4),
        sizes=np.array([n.size for n in state.nodes]),
        nodes=np.concatenate(state.nodes),
        values=np.concatenate(state.fields),
        radii=state.radii,
        clock=np.array([state.time]),
        counters=np.array([state.step, state.phase, state.phase_step]),
        n_dofs=np.array([state.domain.n_dofs]),
        **(observers or {}),
    )
    tmp.replace(path)


def load_mesh_checkpoint(path: str | Path, domain: MeshDomain) -> MeshState:
    """The state saved by :func:`save_mesh_checkpoint`, on ``domain`` (the same mesh)."""
    with np.load(path) as data:
        if int(data["n_dofs"][0]) != domain.n_dofs:
            raise ValueError(f"checkpoint {path} has {int(data['n_dofs'][0])} dofs; the mesh has {domain.n_dofs}")
        cuts = np.cumsum(data["sizes"])[:-1]
        nodes = np.split(data["nodes"], cuts)
        fields = [f.copy() for f in np.split(data["values"], cuts)]
        boxes = [Box(*map(float, row)) for row in data["boxes"]]
        step, phase, phase_step = map(int, data["counters"])
        return MeshState(domain, boxes, nodes, fields, data["radii"].copy(), float(data["clock"][0]),
                         step, phase, phase_step)
