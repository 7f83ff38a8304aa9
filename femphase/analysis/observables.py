"""Frame observables, by name: what a run computes and writes at every frame.

An observable is a class registered in :data:`OBSERVABLES`; a scene lists the names it wants
in ``output.observables`` ("shape" and "energy" are always computed). At a frame the
simulation calls each observable once, in the order of its ``requires``, with the state and
the values computed so far; it returns its columns:

* ``particle_columns``: arrays of length N, one row per particle in ``particles.csv``;
* ``global_columns``: numbers, one row per frame in ``global.csv``.

An observable that keeps a running state across frames (the T1 counter) returns it from
:meth:`Observable.snapshot`; checkpoints store it and a resumed run restores it. A new
observable is one subclass (``docs/architecture.md``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar, Protocol

import numpy as np

from femphase.analysis.lattice import T1Counter, frame_order
from femphase.analysis.shape import DEFAULT_THRESHOLD, present, shape_observables
from femphase.config import Numerics
from femphase.domains.base import Domain
from femphase.errors import SceneError
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.registry import Registry
from femphase.state import State

__all__ = ["OBSERVABLES", "Energy", "Observable", "Order", "RunContext", "Shape", "resolve"]


class RunContext(Protocol):
    """What an observable may read of the simulation that computes it
    (:class:`femphase.run.simulation.Simulation` has it all)."""

    domain: Domain
    energy: FreeEnergy

    @property
    def numerics(self) -> Numerics:
        """The scene's numerics (the window threshold, for the wall-contact flag)."""


class Observable(ABC):
    """A frame observable.

    particle_columns  names of its per-particle values (arrays of length N)
    global_columns    names of its per-frame values (numbers)
    requires          observables whose values it reads (computed before it)
    """

    name: ClassVar[str]
    particle_columns: ClassVar[tuple[str, ...]] = ()
    global_columns: ClassVar[tuple[str, ...]] = ()
    requires: ClassVar[tuple[str, ...]] = ()

    def __init__(self, simulation: RunContext) -> None:
        self.simulation = simulation

    @abstractmethod
    def __call__(self, state: State, values: dict) -> dict:
        """Its columns at this frame (name → value: an array of length N for a particle
        column, a number for a global one). ``values`` holds the columns computed so far
        at this frame, its requirements' among them, per particle and global (a name that is
        both, "area", is the per-particle one there)."""

    def snapshot(self) -> dict[str, np.ndarray]:
        """Running state for a checkpoint (names must be unique across observables)."""
        return {}

    def restore(self, snapshot: dict[str, np.ndarray]) -> None:
        """Continue from a checkpoint's snapshot (all observables' arrays are passed)."""


OBSERVABLES: Registry[type[Observable]] = Registry("Observables", "output.observables")


@OBSERVABLES.register("shape")
class Shape(Observable):
    """Per particle: φ-weighted centroid x, y (lattice units), area ∫φ² (lattice units²),
    elongation r = λ1/λ2 − 1 and orientation θ ∈ (−π/2, π/2] (radians) of the shape tensor
    −∫∇φ∇φᵀ.

    Also wall_contact: 1 when φ > numerics.threshold on a wall dof, else 0; R then misses the
    particle's side along the wall (:mod:`femphase.analysis.shape`, docs/outputs.md)."""

    name = "shape"
    particle_columns = ("x", "y", "area", "elongation", "orientation", "wall_contact")

    def __call__(self, state: State, values: dict) -> dict:
        numerics = getattr(self.simulation, "numerics", None)
        threshold = numerics.threshold if numerics is not None else DEFAULT_THRESHOLD
        shape = shape_observables(state, threshold)
        return {column: getattr(shape, column) for column in self.particle_columns}


@OBSERVABLES.register("energy")
class Energy(Observable):
    """The free energy and one column per term (energy units), computed window by window."""

    name = "energy"

    def __init__(self, simulation: RunContext) -> None:
        super().__init__(simulation)
        self.energy = simulation.energy

    @property
    def global_columns(self) -> tuple[str, ...]:  # type: ignore[override]
        return self.energy.columns

    def __call__(self, state: State, values: dict) -> dict:
        layout, phi = state.flat()
        fields = WindowedFields(phi, layout, state.radii, state.domain.stiffness_apply(layout))
        parts = self.energy.parts(fields)
        return {"free_energy": parts.total, **parts}


@OBSERVABLES.register("order")
class Order(Observable):
    """Ψ6 (bond order) and Ψ2^L (nematic order of the elongation axes, e^{2iθ}) per particle
    (``|ψ6|``, ``|ψ2|``) and per frame (``|mean ψ|``), the lattice angle (radians) and the running count
    of T1 events, from periodic-Delaunay neighbours of the centroids. The T1 counter also
    looks at the centroids between frames, every ``output.t1_interval`` (:meth:`Order.look`)."""

    name = "order"
    particle_columns = ("psi6_abs", "psi2_abs")
    global_columns = ("Psi6", "Psi2", "lattice_angle", "t1_count")
    requires = ("shape",)

    def __init__(self, simulation: RunContext) -> None:
        super().__init__(simulation)
        self.period = simulation.domain.period
        self.t1: T1Counter | None = None
        self._looked_at: float | None = None  # the time of the counter's last look

    def look(self, state: State) -> None:
        """Update the T1 counter with the state's centroids (the shape observable's x, y: NaN
        for a vanished particle, which then has no neighbours)."""
        layout, phi = state.flat()
        centroids = state.domain.centroids(layout, phi)
        centroids[~present(layout, phi)] = np.nan
        self._update(centroids, state.time)

    def snapshot(self) -> dict[str, np.ndarray]:
        return self.t1.snapshot() if self.t1 is not None else {}

    def restore(self, snapshot: dict[str, np.ndarray]) -> None:
        mine = {k: v for k, v in snapshot.items() if k.startswith("t1_")}
        if mine:
            self.t1 = T1Counter.restore(mine, self.period)

    def __call__(self, state: State, values: dict) -> dict:
        centroids = np.stack([values["x"], values["y"]], axis=1)
        order = frame_order(centroids, values["orientation"], self.period)
        self._update(centroids, state.time)
        return {**order, "t1_count": self.t1.count if self.t1 is not None else 0}

    def _update(self, centroids: np.ndarray, time: float) -> None:
        if len(centroids) < 3 or time == self._looked_at:  # a frame right after a look: the same centroids
            return
        if self.t1 is None:
            self.t1 = T1Counter(centroids, self.period)
        else:
            self.t1.update(centroids)
        self._looked_at = time


def resolve(names: tuple[str, ...] | list[str]) -> list[str]:
    """``names`` with everything they require, each after its requirements."""
    ordered: list[str] = []

    def visit(name: str, path: tuple[str, ...] = ()) -> None:
        if name in ordered:
            return
        if name in path:  # a cycle of requirements has no order
            raise SceneError("output.observables", path[0], f"observables whose requirements end: "
                             f"{' → '.join((*path, name))} comes back to {name!r}")
        entry = OBSERVABLES.get(name)
        if not (isinstance(entry, type) and issubclass(entry, Observable)):
            raise SceneError("output.observables", name, f"an Observable subclass registered under {name!r}; "
                             f"{entry!r} is registered")
        for required in entry.requires:
            if required not in OBSERVABLES:
                raise SceneError("output.observables", name, f"observables whose requirements are registered: "
                                 f"{name!r} requires {required!r}, not one of {OBSERVABLES.names()}")
            visit(required, (*path, name))
        ordered.append(name)

    for name in names:
        visit(name)
    return ordered
