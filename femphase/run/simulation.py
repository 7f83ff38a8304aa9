"""A simulation is a state, a stepper per phase and trackers (py-pde style).

``Simulation(scene).run(state, trackers)`` steps through the scene's phases. At every frame
(each phase's frame_interval, plus the initial state) it computes only the observables its
trackers ask for and hands them over; trackers show progress, write run directories or keep
frames in memory, and are composed by the caller.
"""

from __future__ import annotations

import signal
from collections import ChainMap
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from femphase.analysis.observables import OBSERVABLES, Observable, resolve
from femphase.analysis.shape import ShapeObservables
from femphase.config import Numerics
from femphase.errors import ExtensionError, FlowError, Interrupted, SceneError, StopRun
from femphase.model.energy import FreeEnergy, WindowedFields
from femphase.registry import blamed, users_definition
from femphase.scene import Phase, Scene
from femphase.state import State
from femphase.timestepping import Stepper

__all__ = ["METHODS", "Frame", "Simulation", "Tracker"]

#: ``method`` → the time scheme it forces (None: the scene's ``numerics.scheme``).
METHODS = {"fem": None, "fd": "fd-heun"}


class Columns(dict):
    """A frame's values by column, of one table (``table``: "particle" or "global"); a
    column it lacks names what the table holds and why."""

    def __init__(self, table: str = "frame") -> None:
        super().__init__()
        self.table = table

    def __missing__(self, column: str):
        raise KeyError(f"{column!r}: the frame's {self.table} columns are {sorted(self) or 'none'}; a tracker's "
                       "frames carry the columns of the observables its needs name (e.g. needs = "
                       "frozenset({'shape'})) that the scene's output.observables lists")


@dataclass
class Frame:
    """What trackers receive at a frame: the state, its phase and the observables' values,
    per particle (column → array of length N; particles.csv) and global (column → number;
    global.csv). The two may share a name ("area": ∫φ² per particle, the area energy)."""

    state: State
    phase: Phase
    particle: dict = field(default_factory=lambda: Columns("particle"))
    globals: dict = field(default_factory=lambda: Columns("global"))

    @property
    def shape(self) -> ShapeObservables:
        v = self.particle
        return ShapeObservables(v["x"], v["y"], v["area"], v["elongation"], v["orientation"], v.get("wall_contact"))


class Tracker:
    """Base tracker: override what you need.

    ``needs`` names the observables whose values its frames carry (e.g. ``{"shape"}``;
    empty: none, only the state). ``after_step`` runs after every call of the stepper, which
    is one step for fixed-step schemes and up to ``numerics.merged_steps`` steps for the
    adaptive one (:meth:`Simulation.run`); ``frame`` at every frame. Raising
    :class:`~femphase.errors.StopRun` in either ends the run as finished for the tracker's
    purpose, after that step's frames (py-pde's ``FinishedSimulation``): ``run`` returns the
    state, ``finish`` receives the StopRun, a run directory keeps a checkpoint and marks the
    run "interrupted" with the reason. Any other exception ends it as an error (a run
    directory marks it failed)."""

    needs: frozenset = frozenset()

    def start(self, simulation: "Simulation", state: State) -> None: ...

    def after_step(self, state: State) -> None: ...

    def frame(self, frame: Frame) -> None: ...

    def finish(self, state: State, error: Exception | None) -> None: ...


class Simulation:
    """Runs a scene's phases on its domain: ``method="fem"`` with the scene's time scheme,
    ``method="fd"`` with the finite-difference reference ("fd-heun")."""

    def __init__(self, scene: Scene, method: str = "fem", energy: FreeEnergy | None = None) -> None:
        if method not in METHODS:
            raise SceneError("--method", method, f"one of {tuple(METHODS)}")
        if method == "fem" and scene.numerics.scheme == METHODS["fd"]:
            method = "fd"  # the scene's scheme is the FD reference: recorded as what ran
        self.scene, self.method = scene, method
        self.domain = scene.domain
        self.energy = energy or FreeEnergy.paper(scene.model)
        self.observables: dict[str, Observable] = {}

    @property
    def numerics(self) -> Numerics:
        return self.scene.numerics

    def settings(self) -> dict:
        """The resolved scene as this simulation runs it (a run directory's scene.toml and
        run.json's settings): :meth:`~femphase.scene.Scene.to_dict` with the time scheme the
        method forces (``--method fd``: "fd-heun"), not the scene's."""
        settings = self.scene.to_dict()
        if METHODS[self.method] is not None:
            settings["numerics"]["scheme"] = METHODS[self.method]
        return settings

    def observer_state(self) -> dict[str, np.ndarray]:
        """The observables' running state, for a checkpoint."""
        out: dict[str, np.ndarray] = {}
        for observable in self.observables.values():
            out.update(observable.snapshot())
        return out

    def restore_observers(self, snapshot: dict[str, np.ndarray]) -> None:
        """Continue the observables' running state from a checkpoint (a resumed run)."""
        for name in self.scene.output.observables:
            self.observable(name).restore(snapshot)

    def observable(self, name: str) -> Observable:
        if name not in self.observables:
            entry, origin = OBSERVABLES.get(name, "output.observables"), OBSERVABLES.origin(name)
            with blamed(origin, lambda exc: SceneError("output.observables", name, f"an observable built as "
                                                       f"{origin}(simulation): it raised {type(exc).__name__}: {exc}")):
                self.observables[name] = entry(self)
        return self.observables[name]

    def columns(self) -> tuple[list[str], list[str]]:
        """(particle columns, global columns) of the scene's observables, in output order.
        SceneError where two observables, or an observable and the tables' own time, id and
        step, name one column: the later would overwrite the earlier in the outputs."""
        particle: dict[str, str] = dict.fromkeys(("time", "id"), "the table itself")
        global_: dict[str, str] = dict.fromkeys(("time", "step"), "the table itself")
        for name in resolve(self.scene.output.observables):
            for table, columns in ((particle, self.observable(name).particle_columns),
                                   (global_, self.observable(name).global_columns)):
                for column in columns:
                    if column in table:
                        raise SceneError("output.observables", name, f"observables whose columns differ: {name!r} "
                                         f"names the column {column!r}, which {table[column]} has already")
                    table[column] = f"the observable {name!r}"
        return list(particle)[2:], list(global_)[2:]

    def stepper(self, phase: Phase, radii: np.ndarray) -> Stepper:
        return Stepper(self.domain, self.scene.model, self.scene.numerics, phase.dt, self.scene.flow(phase),
                       radii, energy=self.energy, scheme=METHODS[self.method])

    def total_steps(self) -> int:
        return sum(p.n_steps for p in self.scene.phases)

    def steps_done(self, state: State) -> int:
        return sum(p.n_steps for p in self.scene.phases[: state.phase]) + state.phase_step

    def run(self, state: State, trackers: list[Tracker] | Tracker = (), *, initial_frame: bool | None = None,
            stop: Callable[[], int | None] | None = None) -> State:
        """Step ``state`` (in place) through the remaining phases; returns it.

        ``trackers``: a list of :class:`Tracker`, or one.

        ``initial_frame``: emit a frame of the state before the first step (default: when
        it is at step 0; a resumed run has it already). ``stop()`` is asked after every call
        of the stepper (a consistent state): after every step, or, for a scheme that merges
        steps (the adaptive default), every few (:meth:`_steps_per_call`). A signal number
        from it stops the run with :class:`~femphase.errors.Interrupted`. Trackers'
        ``after_step`` runs after every call too.

        A state stopped part-way continues bit for bit in this Simulation or a new one of the
        same scene; the running T1 count (``t1_count``) lives in the Simulation's observers,
        so a new one starts it from 0 unless given the old one's :meth:`observer_state`
        through :meth:`restore_observers` (a run directory's checkpoint carries it). A state
        on another domain, or past the end of a phase of this scene, is refused (ValueError);
        observables whose columns clash, or that return other than their columns, are refused
        (SceneError naming the observable)."""
        if not isinstance(state, State):
            raise TypeError(f"state must be a femphase State (scene.initial_state(), or a checkpoint's), "
                            f"not {type(state).__name__}")
        self._check_state(state)
        self._check_energy_terms(state)
        self.columns()  # observables that clash are refused before any step
        trackers = [trackers] if isinstance(trackers, Tracker) else list(trackers)
        if not all(isinstance(tracker, Tracker) for tracker in trackers):
            raise TypeError(f"trackers must be Tracker instances (femphase.run), not "
                            f"{sorted({type(t).__name__ for t in trackers if not isinstance(t, Tracker)})}")
        for tracker in trackers:  # a misspelt need left its frames empty without a word
            unknown = sorted(set(tracker.needs) - set(OBSERVABLES.names()))
            if unknown:
                raise ValueError(f"the tracker {type(tracker).__name__} needs {unknown}, which name no observable; "
                                 f"observables: {list(OBSERVABLES.names())}")
        needs = frozenset().union(*(t.needs for t in trackers)) if trackers else frozenset()
        t1_counter = self._t1_counter(needs)
        error = None
        for tracker in trackers:
            tracker.start(self, state)
        try:
            if (state.step == 0 if initial_frame is None else initial_frame):
                request = self._frame(state, self.scene.phases[min(state.phase, len(self.scene.phases) - 1)],
                                      trackers, needs)
                if request is not None:
                    raise request
            while state.phase < len(self.scene.phases):
                phase = self.scene.phases[state.phase]
                stepper = self.stepper(phase, state.radii)
                if state.phase_step == 0:
                    stepper.scheme.start_phase(state)
                while state.phase_step < phase.n_steps:
                    steps = (self._steps_per_call(state, phase, t1_counter is not None)
                             if stepper.scheme.merges_steps else 1)
                    stepper.step(state, steps)
                    state.phase_step += steps
                    if t1_counter is not None and self._t1_look_due(state.time, phase.dt):
                        t1_counter.look(state)
                    # a tracker's StopRun waits until the step's bookkeeping and frame are done
                    request = _stop_requests(lambda tracker: tracker.after_step(state), trackers)
                    finished = state.phase_step == phase.n_steps
                    if finished:
                        # the frame's checkpoint must resume in the next phase
                        state.phase, state.phase_step = state.phase + 1, 0
                    if finished or state.phase_step % phase.steps_per_frame == 0:
                        request = self._frame(state, phase, trackers, needs) or request
                    if request is not None:
                        raise request
                    number = stop() if stop is not None else None
                    if number is not None:
                        raise Interrupted(signal.Signals(number).name, 128 + number, state.step, state.time)
                    if finished:
                        break
        except StopRun as exc:  # a tracker's end, at a consistent state: trackers see why, the run returns
            error = exc
        except FlowError as exc:  # a user's flow function failed: name the step the run stands at
            error = FlowError(exc.function, exc.time, exc.reason, state.step)
            raise error from exc.__cause__
        except BaseException as exc:  # interrupted runs are recorded as failed too
            error = exc
            raise
        finally:
            for tracker in trackers:
                tracker.finish(state, error)
        return state

    def _check_energy_terms(self, state: State) -> None:
        """ValueError naming a free-energy term of the user's own (defined outside femphase)
        whose energy is no finite number, or whose explicit derivative is not one finite
        value per position, at ``state``: inside the stepper it was a numpy error naming
        neither the term nor what it returned."""
        layout, phi = state.flat()
        fields = WindowedFields(phi, layout, state.radii)
        for term in self.energy.terms:
            origin = users_definition(type(term))
            if origin is None:
                continue
            name = f"the energy term {term.name!r} ({origin})"
            energy = term.energy(fields)
            if not (np.ndim(energy) == 0 and np.isrealobj(energy) and np.isfinite(energy)):
                raise ValueError(f"{name}: energy() must return one finite number; it returned "
                                 f"{type(energy).__name__} of shape {np.shape(energy)}")
            derivative = np.asarray(term.explicit_derivative(fields))
            if derivative.shape != phi.shape or not np.isfinite(derivative).all():
                raise ValueError(f"{name}: explicit_derivative() must return one finite value per position of the "
                                 f"layout, shape {phi.shape}; it returned shape {derivative.shape}"
                                 + ("" if derivative.shape != phi.shape else " with values that are not finite"))

    def _check_state(self, state: State) -> None:
        """ValueError for a state this scene cannot continue: one on another domain (its
        windows index another mesh), or one past the end of a phase of this scene (a state
        stopped under a scene whose phase was longer; the loop would never leave it)."""
        if state.domain is not self.domain and state.domain.describe() != self.domain.describe():
            raise ValueError(f"the state lives on another domain ({state.domain.describe()}) than this scene's "
                             f"({self.domain.describe()}); build it from this scene (scene.initial_state())")
        phases = self.scene.phases
        if state.phase > len(phases) or (state.phase < len(phases) and state.phase_step > phases[state.phase].n_steps):
            where = (f"phase {state.phase}, of {len(phases)}" if state.phase > len(phases) else
                     f"step {state.phase_step} of phase {state.phase}, which has {phases[state.phase].n_steps}")
            raise ValueError(f"the state stands at {where} in this scene: it ran under a longer one, and this scene "
                             "cannot continue it (shorten no phase a state has entered)")

    def _steps_per_call(self, state: State, phase: Phase, t1_looks: bool) -> int:
        """Steps of the next stepper call: up to the next frame, T1 look (``t1_looks``) or phase
        end, and to the next multiple of ``numerics.merged_steps`` steps of the phase,
        whichever comes first. Each is fixed by the phase's step count or the clock, so a run resumed
        from any call's end takes the same calls as one that was never stopped (a scheme that
        merges steps gives results that depend on where calls end)."""
        done = state.phase_step
        steps = min(phase.n_steps - done, phase.steps_per_frame - done % phase.steps_per_frame,
                    self.scene.numerics.merged_steps - done % self.scene.numerics.merged_steps)
        if t1_looks:
            time = state.time
            for taken in range(1, steps):
                time += phase.dt
                if self._t1_look_due(time, phase.dt):
                    return taken
        return steps

    def _t1_counter(self, needs: frozenset) -> Observable | None:
        """The "order" observable, whose T1 counter looks between frames, if the scene and
        a tracker want it (else None)."""
        wanted = "order" in needs and "order" in self.scene.output.observables
        return self.observable("order") if wanted else None

    def _t1_look_due(self, time: float, dt: float) -> bool:
        """Whether the step that ended at ``time`` reached a multiple of output.t1_interval
        (by the clock alone, so that a resumed run looks at the same steps)."""
        interval = self.scene.output.t1_interval
        return np.floor(time / interval + 1e-9) > np.floor((time - dt) / interval + 1e-9)

    def _frame(self, state: State, phase: Phase, trackers: list[Tracker], needs: frozenset) -> StopRun | None:
        """Compute the frame's values and hand them to every tracker; a tracker's StopRun,
        returned once all have had the frame."""
        frame = Frame(state, phase)
        # only what a tracker uses and the scene asked for
        for name in resolve([name for name in self.scene.output.observables if name in needs]):
            observable = self.observable(name)
            # the values so far, per particle first where a name is both ("area")
            values = _observed(observable, name, state, ChainMap(frame.particle, frame.globals))
            frame.particle.update(_frame_values(observable, values, observable.particle_columns, state.n_particles))
            frame.globals.update(_frame_values(observable, values, observable.global_columns, None))
        return _stop_requests(lambda tracker: tracker.frame(frame), trackers)


def _observed(observable: Observable, name: str, state: State, so_far: ChainMap) -> dict:
    """What ``observable`` returns for ``state``: a user's observable that raises stops the
    run naming it (ExtensionError), one that returns other than a mapping is refused."""
    origin = OBSERVABLES.origin(name)
    with blamed(origin, lambda exc: ExtensionError(f"the observable {name!r} ({origin})", state.step, state.time,
                                                   f"it raised {type(exc).__name__}: {exc}")):
        values = observable(state, so_far)
    if not isinstance(values, Mapping):
        raise SceneError("output.observables", name, f"an observable that returns a mapping of its columns; it "
                         f"returned {type(values).__name__}")
    return values


def _frame_values(observable: Observable, values: dict, columns: tuple[str, ...], n_particles: int | None) -> dict:
    """``observable``'s ``columns`` from what it returned: arrays of one value per particle
    (``n_particles``), or numbers (None); SceneError naming it and the column otherwise."""
    out = {}
    for column in columns:
        if column not in values:
            raise SceneError("output.observables", observable.name, f"an observable that returns its columns: "
                             f"{column!r} is missing from what it returned ({sorted(values)})")
        value = np.asarray(values[column])
        wanted = "a number" if n_particles is None else f"an array of one value per particle ({n_particles},)"
        if value.shape != (() if n_particles is None else (n_particles,)) or value.dtype.kind not in "biuf":
            raise SceneError("output.observables", observable.name, f"an observable whose column {column!r} is "
                             f"{wanted}; it returned {value.dtype} of shape {value.shape}")
        out[column] = values[column]
    return out


def _stop_requests(call: Callable[[Tracker], None], trackers: list[Tracker]) -> StopRun | None:
    """``call`` on every tracker; the first :class:`~femphase.errors.StopRun` one raised."""
    request = None
    for tracker in trackers:
        try:
            call(tracker)
        except StopRun as exc:
            request = request or exc
    return request
