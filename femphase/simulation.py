"""A simulation is a state, a stepper per phase and trackers (py-pde style).

``Simulation(scene).run(state, trackers)`` steps through the scene's phases. At every frame
(each phase's frame_interval, plus the initial state) it computes only the observables its
trackers ask for and hands them over; trackers show progress, write run directories or keep
frames in memory, and are composed by the caller.
"""

from __future__ import annotations

import time as wallclock
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import __version__
from .analysis.shape import ShapeObservables
from .energy import FreeEnergy
from .errors import SceneError
from .io import CsvWriter, FieldWriter, load_checkpoint, point_data, save_checkpoint, to_toml, write_json
from .observables import OBSERVABLES, Observable, resolve
from .scene import Phase, Scene
from .state import State
from .stepping import Stepper

#: ``method`` → the time scheme it forces (None: the scene's ``numerics.scheme``).
METHODS = {"fem": None, "fd": "fd-heun"}


@dataclass
class Frame:
    """What trackers receive at a frame: the state, its phase and the observables' values,
    per particle (column → array of length N; particles.csv) and global (column → number;
    global.csv). The two may share a name ("area": ∫φ² per particle, the area energy)."""

    state: State
    phase: Phase
    particle: dict = field(default_factory=dict)
    globals: dict = field(default_factory=dict)

    @property
    def shape(self) -> ShapeObservables:
        v = self.particle
        return ShapeObservables(v["x"], v["y"], v["area"], v["elongation"], v["orientation"])


class Tracker:
    """Base tracker: override what you need. ``needs`` names the observables it uses."""

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
        self.scene, self.method = scene, method
        self.domain = scene.domain
        self.energy = energy or FreeEnergy.paper(scene.model)
        self.observables: dict[str, Observable] = {}

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
            self.observables[name] = OBSERVABLES.get(name)(self)
        return self.observables[name]

    def columns(self) -> tuple[list[str], list[str]]:
        """(particle columns, global columns) of the scene's observables, in output order."""
        particle, global_ = [], []
        for name in resolve(self.scene.output.observables):
            particle += self.observable(name).particle_columns
            global_ += self.observable(name).global_columns
        return particle, global_

    def stepper(self, phase: Phase, radii: np.ndarray) -> Stepper:
        return Stepper(self.domain, self.scene.model, self.scene.numerics, phase.dt, self.scene.flow(phase),
                       radii, energy=self.energy, scheme=METHODS[self.method])

    def total_steps(self) -> int:
        return sum(p.n_steps for p in self.scene.phases)

    def steps_done(self, state: State) -> int:
        return sum(p.n_steps for p in self.scene.phases[: state.phase]) + state.phase_step

    def run(self, state: State, trackers: list[Tracker] = ()) -> State:
        """Step ``state`` (in place) through the remaining phases; returns it."""
        trackers = list(trackers)
        needs = frozenset().union(*(t.needs for t in trackers)) if trackers else frozenset()
        error = None
        for tracker in trackers:
            tracker.start(self, state)
        try:
            if state.step == 0:
                self._frame(state, self.scene.phases[0], trackers, needs)
            while state.phase < len(self.scene.phases):
                phase = self.scene.phases[state.phase]
                stepper = self.stepper(phase, state.radii)
                while state.phase_step < phase.n_steps:
                    stepper.step(state)
                    state.phase_step += 1
                    for tracker in trackers:
                        tracker.after_step(state)
                    finished = state.phase_step == phase.n_steps
                    if finished:
                        # the frame's checkpoint must resume in the next phase
                        state.phase, state.phase_step = state.phase + 1, 0
                    if finished or state.phase_step % phase.steps_per_frame == 0:
                        self._frame(state, phase, trackers, needs)
                    if finished:
                        break
        except BaseException as exc:  # interrupted runs are recorded as failed too
            error = exc
            raise
        finally:
            for tracker in trackers:
                tracker.finish(state, error)
        return state

    def _frame(self, state: State, phase: Phase, trackers: list[Tracker], needs: frozenset) -> None:
        frame = Frame(state, phase)
        # only what a tracker uses and the scene asked for
        for name in resolve([name for name in self.scene.output.observables if name in needs]):
            observable = self.observable(name)
            values = observable(state, frame.particle)
            frame.particle.update({c: values[c] for c in observable.particle_columns})
            frame.globals.update({c: values[c] for c in observable.global_columns})
        for tracker in trackers:
            tracker.frame(frame)


class ProgressBar(Tracker):
    """A tqdm progress bar over steps, showing simulated time, steps/s and ETA."""

    def __init__(self, disable: bool | None = None) -> None:
        self.disable = disable

    def start(self, simulation: Simulation, state: State) -> None:
        from tqdm import tqdm

        self.simulation = simulation
        self.bar = tqdm(
            total=simulation.total_steps(), initial=simulation.steps_done(state), unit="step",
            disable=self.disable, dynamic_ncols=True, mininterval=0.5,
        )

    def after_step(self, state: State) -> None:
        self.bar.update(1)
        if state.step % 200 == 0:
            self.bar.set_postfix_str(f"t={state.time:.6g}", refresh=False)

    def finish(self, state: State, error: Exception | None) -> None:
        self.bar.set_postfix_str(f"t={state.time:.6g}", refresh=False)
        self.bar.close()


class FrameRecorder(Tracker):
    """Keeps every frame's state and observables in memory (for scripts, tests, notebooks)."""

    needs = frozenset({"shape", "energy", "order"})

    def __init__(self) -> None:
        self.frames: list[Frame] = []

    def frame(self, frame: Frame) -> None:
        self.frames.append(Frame(frame.state.copy(), frame.phase, dict(frame.particle), dict(frame.globals)))

    def series(self, name: str, kind: str = "particle") -> np.ndarray:
        """(n_frames, N) array of a per-particle column (e.g. "elongation"), or with
        kind="global" (n_frames,) of a global one (e.g. "free_energy")."""
        return np.stack([np.asarray(getattr(f, "globals" if kind == "global" else "particle")[name])
                         for f in self.frames])

    @property
    def times(self) -> np.ndarray:
        return np.array([f.state.time for f in self.frames])


class RunDirectory(Tracker):
    """Writes the run directory described in :mod:`femphase.io`."""

    def __init__(self, directory: str | Path, resume: bool = False) -> None:
        self.directory = Path(directory)
        self.resume = resume
        self.needs = frozenset(OBSERVABLES.names())

    def start(self, simulation: Simulation, state: State) -> None:
        scene = simulation.scene
        self.simulation = simulation
        self.directory.mkdir(parents=True, exist_ok=True)
        keep = state.time if self.resume else None
        (self.directory / "scene.toml").write_text(to_toml(scene.to_dict()))
        self.particle_columns, self.global_columns = simulation.columns()
        self.particles = CsvWriter(self.directory / "particles.csv", ["time", "id"] + self.particle_columns, keep)
        self.globals = CsvWriter(self.directory / "global.csv", ["time", "step"] + self.global_columns, keep)
        self.fields = FieldWriter(self.directory, simulation.domain.mesh, keep) if scene.output.fields else None
        self.started = wallclock.perf_counter()
        self.first_step = state.step

    def frame(self, frame: Frame) -> None:
        state = frame.state
        columns = np.column_stack([np.full(state.n_particles, state.time), np.arange(state.n_particles)]
                                  + [np.asarray(frame.particle[c], dtype=float) for c in self.particle_columns])
        self.particles.write_rows([[row[0], int(row[1]), *row[2:]] for row in columns.tolist()])
        self.globals.write_rows([[state.time, state.step] + [frame.globals[c] for c in self.global_columns]])
        output = self.simulation.scene.output
        if self.fields is not None:
            self.fields.write(state.time, point_data(state, output.per_particle_fields))
        if output.checkpoint:
            save_checkpoint(self.directory / CHECKPOINT, state, self.simulation.observer_state())

    def finish(self, state: State, error: Exception | None) -> None:
        for writer in (self.particles, self.globals, self.fields):
            if writer is not None:
                writer.close()
        scene = self.simulation.scene
        write_json(self.directory / "run.json", {
            "femphase_version": __version__,
            "method": self.simulation.method,
            "scene": scene.name,
            "settings": scene.to_dict(),
            "steps": state.step,
            "steps_this_session": state.step - self.first_step,
            "time": state.time,
            "wall_time_s": wallclock.perf_counter() - self.started,
            "status": "completed" if error is None else "failed",
            "message": "" if error is None else (str(error) or type(error).__name__),
            "resumed": self.resume,
        })


#: The checkpoint's file name in a run directory.
CHECKPOINT = "checkpoint.h5"


def run_scene(scene: Scene, directory: str | Path, *, resume: bool = False, method: str = "fem",
              progress: bool | None = None) -> State:
    """Run a scene into a run directory (what ``femphase run`` does), on any domain."""
    directory = Path(directory)
    simulation = Simulation(scene, method)
    if resume:
        checkpoint = directory / CHECKPOINT
        if not checkpoint.exists():
            raise SceneError("--resume", str(directory), f"a run directory that holds {CHECKPOINT}")
        state, observers = load_checkpoint(checkpoint, simulation.domain)
        simulation.restore_observers(observers)
    else:
        state = scene.initial_state()
    trackers: list[Tracker] = [RunDirectory(directory, resume)]
    if progress is not False:
        trackers.insert(0, ProgressBar(disable=None if progress is None else not progress))
    return simulation.run(state, trackers)
