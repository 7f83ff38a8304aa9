"""A simulation is a state, a stepper per phase and trackers (py-pde style).

``Simulation(scene).run(state, trackers)`` steps through the scene's phases. At every frame
(each phase's frame_interval, plus the initial state) it computes only the observables its
trackers ask for and hands them over; trackers show progress, write run directories or keep
frames in memory, and are composed by the caller.
"""

from __future__ import annotations

import time as wallclock
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import __version__
from .analysis.order import OrderObserver
from .analysis.shape import ShapeObservables, shape_observables
from .energy import FreeEnergy, free_energy
from .errors import SceneError
from .io import (
    GLOBAL_COLUMNS, ORDER_GLOBAL_COLUMNS, ORDER_PARTICLE_COLUMNS, PARTICLE_COLUMNS,
    CsvWriter, FieldWriter, load_checkpoint, load_observers, point_data, save_checkpoint, to_toml, write_json,
)
from .scene import Phase, Scene
from .state import State
from .stepping import SemiImplicitStepper

METHODS = ("fem", "fd")


@dataclass
class Frame:
    """What trackers receive at a frame; observables not asked for are None."""

    state: State
    phase: Phase
    shape: ShapeObservables | None = None
    energy: FreeEnergy | None = None
    order: dict | None = None


class Tracker:
    """Base tracker: override what you need. ``needs`` names the observables it uses."""

    needs: frozenset = frozenset()

    def start(self, simulation: "Simulation", state: State) -> None: ...

    def after_step(self, state: State) -> None: ...

    def frame(self, frame: Frame) -> None: ...

    def finish(self, state: State, error: Exception | None) -> None: ...


class Simulation:
    """Runs a scene's phases with the finite-element (``method="fem"``) or the
    finite-difference reference (``method="fd"``) stepper."""

    def __init__(self, scene: Scene, method: str = "fem", observers: dict[str, np.ndarray] | None = None) -> None:
        """``observers``: the running state of the frame observers from a checkpoint
        (:func:`femphase.io.load_observers`), so a resumed run continues its T1 count."""
        if method not in METHODS:
            raise SceneError("--method", method, f"one of {METHODS}")
        self.scene, self.method = scene, method
        self.discretisation = scene.discretisation()
        self._order: OrderObserver | None = None
        self._observers = observers or None

    def observers(self) -> dict[str, np.ndarray]:
        """The frame observers' running state, for a checkpoint."""
        return self._order.snapshot() if self._order is not None else {}

    def stepper(self, phase: Phase, radii: np.ndarray):
        flow = self.scene.flow(phase)
        if self.method == "fd":
            from .fd import FiniteDifferenceStepper

            cls = FiniteDifferenceStepper
        else:
            cls = SemiImplicitStepper
        return cls(self.discretisation, self.scene.model, self.scene.numerics, phase.dt, flow, radii)

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

    def shape(self, state: State) -> ShapeObservables:
        """The shape observables of a state (the meshed path overrides this)."""
        return shape_observables(state, self.discretisation.operators)

    def period_x(self) -> float:
        """The channel's period in x (lattice units)."""
        return self.discretisation.grid.length

    def _frame(self, state: State, phase: Phase, trackers: list[Tracker], needs: frozenset) -> None:
        frame = Frame(state, phase)
        if "shape" in needs:
            frame.shape = self.shape(state)
        if "energy" in needs:
            frame.energy = free_energy(state.global_fields(), state.radii, self.scene.model,
                                       self.discretisation.operators)
        if "order" in needs and "order" in self.scene.output.observables:
            if self._order is None:
                self._order = OrderObserver(self.period_x(), self._observers)
            frame.order = self._order(frame.shape)
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
    """Keeps every frame's observables in memory (for scripts, tests and notebooks)."""

    needs = frozenset({"shape", "energy", "order"})

    def __init__(self) -> None:
        self.frames: list[Frame] = []

    def frame(self, frame: Frame) -> None:
        self.frames.append(Frame(frame.state.copy(), frame.phase, frame.shape, frame.energy, frame.order))

    def series(self, name: str) -> np.ndarray:
        """(n_frames, N) array of a shape observable, e.g. "elongation"."""
        return np.stack([getattr(f.shape, name) for f in self.frames])

    @property
    def times(self) -> np.ndarray:
        return np.array([f.state.time for f in self.frames])


class RunDirectory(Tracker):
    """Writes the run directory described in :mod:`femphase.io`."""

    def __init__(self, directory: str | Path, resume: bool = False) -> None:
        self.directory = Path(directory)
        self.resume = resume
        self.needs = frozenset({"shape", "energy", "order"})

    def start(self, simulation: Simulation, state: State) -> None:
        scene = simulation.scene
        self.simulation = simulation
        self.directory.mkdir(parents=True, exist_ok=True)
        keep = state.time if self.resume else None
        order = "order" in scene.output.observables
        (self.directory / "scene.toml").write_text(to_toml(scene.to_dict()))
        self.particles = CsvWriter(
            self.directory / "particles.csv", PARTICLE_COLUMNS + (ORDER_PARTICLE_COLUMNS if order else []), keep
        )
        self.globals = CsvWriter(
            self.directory / "global.csv", GLOBAL_COLUMNS + (ORDER_GLOBAL_COLUMNS if order else []), keep
        )
        self.fields = (
            FieldWriter(self.directory, simulation.discretisation.mesh, keep) if scene.output.fields else None
        )
        self.started = wallclock.perf_counter()
        self.first_step = state.step

    def frame(self, frame: Frame) -> None:
        state, shape, energy = frame.state, frame.shape, frame.energy
        order = frame.order or {}
        rows = []
        for i in range(state.n_particles):
            row = [state.time, i, shape.x[i], shape.y[i], shape.area[i], shape.elongation[i], shape.orientation[i]]
            if order:
                row += [abs(order["psi6"][i]), abs(order["psi2"][i])]
            rows.append(row)
        self.particles.write_rows(rows)
        row = [state.time, state.step, energy.total, energy.interface, energy.area, energy.repulsion]
        if order:
            row += [order["Psi6"], order["Psi2"], order["lattice_angle"], order["t1_count"]]
        self.globals.write_rows([row])
        if self.fields is not None:
            output = self.simulation.scene.output
            self.fields.write(state.time, point_data(state, self.simulation.discretisation.dof_map, output.per_particle_fields))
        if self.simulation.scene.output.checkpoint:
            save_checkpoint(self.directory / "checkpoint.npz", state, self.simulation.observers())

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


def run_scene(scene: Scene, directory: str | Path, *, resume: bool = False, method: str = "fem",
              progress: bool | None = None) -> State:
    """Run a scene into a run directory (what ``femphase run`` does)."""
    directory = Path(directory)
    checkpoint = directory / "checkpoint.npz"
    if resume:
        if not checkpoint.exists():
            raise SceneError("--resume", str(directory), "a run directory that holds checkpoint.npz")
        state = load_checkpoint(checkpoint)
        simulation = Simulation(scene, method, load_observers(checkpoint))
    else:
        state = scene.initial_state()
        simulation = Simulation(scene, method)
    trackers: list[Tracker] = [RunDirectory(directory, resume)]
    if progress is not False:
        trackers.insert(0, ProgressBar(disable=None if progress is None else not progress))
    return simulation.run(state, trackers)
