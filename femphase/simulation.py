"""A simulation is a state, a stepper per phase and trackers (py-pde style).

``Simulation(scene).run(state, trackers)`` steps through the scene's phases. At every frame
(each phase's frame_interval, plus the initial state) it computes only the observables its
trackers ask for and hands them over; trackers show progress, write run directories or keep
frames in memory, and are composed by the caller.
"""

from __future__ import annotations

import logging
import shlex
import signal
import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from . import __version__
from .analysis.shape import ShapeObservables
from .energy import FreeEnergy
from .errors import Interrupted, SceneError
from .io import atomic_write, load_checkpoint, point_data, read_checkpoint_metadata, save_checkpoint, to_toml
from .observables import OBSERVABLES, Observable, resolve
from .provenance import provenance
from .rundir import CHECKPOINT, Outputs, RunLog, Status, prepare_directory, resume_position
from .scene import Phase, Scene, check_numerics
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

    def run(self, state: State, trackers: list[Tracker] = (), *, initial_frame: bool | None = None,
            stop: Callable[[], int | None] | None = None) -> State:
        """Step ``state`` (in place) through the remaining phases; returns it.

        ``initial_frame``: emit a frame of the state before the first step (default: when
        it is at step 0; a resumed run has it already). ``stop()`` is asked after every call
        of the stepper (a consistent state): after every step, or, for a scheme that merges
        steps (the adaptive default), every few (:meth:`_steps_per_call`). A signal number
        from it stops the run with :class:`~femphase.errors.Interrupted`. Trackers'
        ``after_step`` runs after every call too."""
        trackers = list(trackers)
        needs = frozenset().union(*(t.needs for t in trackers)) if trackers else frozenset()
        t1_counter = self._t1_counter(needs)
        error = None
        for tracker in trackers:
            tracker.start(self, state)
        try:
            if (state.step == 0 if initial_frame is None else initial_frame):
                self._frame(state, self.scene.phases[min(state.phase, len(self.scene.phases) - 1)], trackers, needs)
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
                    for tracker in trackers:
                        tracker.after_step(state)
                    finished = state.phase_step == phase.n_steps
                    if finished:
                        # the frame's checkpoint must resume in the next phase
                        state.phase, state.phase_step = state.phase + 1, 0
                    if finished or state.phase_step % phase.steps_per_frame == 0:
                        self._frame(state, phase, trackers, needs)
                    number = stop() if stop is not None else None
                    if number is not None:
                        raise Interrupted(signal.Signals(number).name, 128 + number, state.step, state.time)
                    if finished:
                        break
        except BaseException as exc:  # interrupted runs are recorded as failed too
            error = exc
            raise
        finally:
            for tracker in trackers:
                tracker.finish(state, error)
        return state

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
        self.bar.update(self.simulation.steps_done(state) - self.bar.n)
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
    """Writes a run directory (:mod:`femphase.rundir`): appends every frame's rows and field
    frame, then its checkpoint; keeps run.json's status current; appends the femphase
    logger's records to run.log while it runs (:class:`femphase.rundir.RunLog`).

    ``resume_from``: the checkpoint's record of the outputs (a resumed run cuts them back to
    it); ``changes``: what the resumed scene changed; ``argv``: the command line (without
    the program) and ``sets``: its ``--set`` assignments (run.json's segment records all
    three); ``overwrite``: replace a run already in the directory (else it is refused,
    :func:`femphase.rundir.prepare_directory`)."""

    def __init__(self, directory: str | Path, resume_from: dict | None = None, changes: list[str] | None = None,
                 argv: list[str] | None = None, overwrite: bool = False, sets: list[str] | None = None) -> None:
        self.directory = Path(directory)
        self.resume_from, self.changes, self.argv, self.overwrite = resume_from, list(changes or []), argv, overwrite
        self.sets = list(sets or [])
        self.needs = frozenset(OBSERVABLES.names())

    def start(self, simulation: Simulation, state: State) -> None:
        scene = simulation.scene
        self.simulation = simulation
        prepare_directory(self.directory, resume=self.resume_from is not None, overwrite=self.overwrite)
        particle_columns, global_columns = simulation.columns()
        self.outputs = Outputs(self.directory, particle_columns, global_columns, scene.output.fields)
        self.particle_columns, self.global_columns = particle_columns, global_columns
        mesh = simulation.domain.mesh
        if self.resume_from is None:
            self.outputs.start_new(mesh)
        else:
            self.outputs.start_from(self.resume_from, mesh)  # checks every file before it cuts any
        atomic_write(self.directory / "scene.toml", to_toml(scene.to_dict()))
        self.status = Status(self.directory, {
            "femphase_version": __version__, "method": simulation.method, "scene": scene.name,
            "settings": scene.to_dict(),
        }, Status.read(self.directory) if self.resume_from is not None else None)
        origin = provenance()
        self.status.begin_segment({"resumed": self.resume_from is not None, "from_time": state.time,
                                   "from_step": state.step, "changes": self.changes, "argv": self.argv,
                                   "set": self.sets, "provenance": origin})
        self.first_step = state.step
        self.status.update(status="running", message="", time=state.time, steps=state.step)
        # last: a refusal above must leave run.log untouched, and nothing below can fail
        self.log = RunLog(self.directory, (
            f"=== segment {len(self.status.data['segments'])}: "
            f"{'resumed' if self.resume_from is not None else 'started'} at t = {state.time:g} (step {state.step});"
            f" femphase {origin['femphase_version']} (git {origin['git_commit'] or 'unknown'}), Python {origin['python']},"
            f" host {origin['host']}, pid {origin['pid']}"
            + (f"; argv: {shlex.join(self.argv)}" if self.argv is not None else "")
            + (f"; WARNING: source changed since this process imported it: "
               f"{', '.join(origin['source_changed_since_import'])} (it runs the code it imported, not git's)"
               if origin["source_changed_since_import"] else "") + " ==="))

    def frame(self, frame: Frame) -> None:
        state = frame.state
        columns = np.column_stack([np.full(state.n_particles, state.time), np.arange(state.n_particles)]
                                  + [np.asarray(frame.particle[c], dtype=float) for c in self.particle_columns])
        self.outputs.append_rows("particles.csv", ([row[0], int(row[1]), *row[2:]] for row in columns.tolist()))
        self.outputs.append_rows("global.csv", [[state.time, state.step] + [frame.globals[c] for c in self.global_columns]])
        output = self.simulation.scene.output
        if output.fields:
            self.outputs.append_fields(state.time, point_data(state, output.per_particle_fields), self.simulation.domain.mesh)
        if output.checkpoint:
            self._checkpoint(state)
        self.status.update(time=state.time, steps=state.step)

    def _checkpoint(self, state: State) -> None:
        save_checkpoint(self.directory / CHECKPOINT, state, self.simulation.observer_state(), {
            "scene": self.simulation.scene.to_dict(), "outputs": self.outputs.record(),
            "method": self.simulation.method, "time": state.time,
        })

    def finish(self, state: State, error: Exception | None) -> None:
        if error is None:
            status, message, level = "completed", "", logging.INFO
        elif isinstance(error, (Interrupted, KeyboardInterrupt)):
            status, message, level = "interrupted", str(error) or "interrupted (KeyboardInterrupt)", logging.WARNING
        else:
            status, message, level = "failed", str(error) or type(error).__name__, logging.ERROR
        try:
            if isinstance(error, Interrupted) and self.simulation.scene.output.checkpoint:
                self._checkpoint(state)  # a consistent state between two steps: keep it
            self.outputs.close()
            self.status.update(status=status, message=message, time=state.time, steps=state.step,
                               steps_this_segment=state.step - self.first_step)
        finally:  # the logger must not keep writing into this directory
            segment = self.status.data["segments"][-1]
            self.log.close(level, f"=== segment {len(self.status.data['segments'])} {status} after step {state.step} "
                                  f"(t = {state.time:g}), {segment['wall_time_s']:.1f} s wall time"
                                  + (f": {message}" if message else "") + " ===")


@contextmanager
def stop_on_signals():
    """While active, SIGINT and SIGTERM (what Ctrl-C, ``timeout``, Slurm and ``docker stop``
    send) ask the run to stop after the current step: yields the ``stop`` callable of
    :meth:`Simulation.run`. A second signal interrupts at once. Outside the main thread
    signals cannot be caught, and ``stop`` never fires."""
    received: list[int] = []

    def handler(number, frame):
        if received:
            raise KeyboardInterrupt
        received.append(number)

    def stop() -> int | None:
        return received[0] if received else None

    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = {number: signal.signal(number, handler) for number in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for number, old in previous.items():
            signal.signal(number, old)


def run_scene(scene: Scene, directory: str | Path, *, resume: bool = False, overwrite: bool = False,
              method: str = "fem", progress: bool | None = None, argv: list[str] | None = None,
              sets: list[str] | None = None, status_interval: float | None = 30.0) -> State:
    """Run a scene into a run directory (what ``femphase run`` does), on any domain.

    A directory that already holds a run is refused unless ``resume`` (continue from its
    checkpoint; the scene may change only compatibly, :func:`femphase.rundir.resume_position`)
    or ``overwrite``. Nothing in the directory is touched before every check has passed.
    ``progress``: the tqdm bar (None: only on a terminal); ``argv`` and ``sets``: the command
    line and its ``--set`` assignments, for run.json; ``status_interval``: seconds of wall
    time between status lines in the log (:class:`femphase.logs.StatusLog`; None: none)."""
    directory = Path(directory)
    simulation = Simulation(scene, method)
    check_numerics(scene, METHODS[method])  # what the first step would refuse, refused before any write
    prepare_directory(directory, resume=resume, overwrite=overwrite)
    record, changes = None, []
    if resume:
        checkpoint = directory / CHECKPOINT
        metadata = read_checkpoint_metadata(checkpoint)
        if not {"scene", "outputs", "time"} <= set(metadata):
            raise SceneError("--resume", str(checkpoint), "a checkpoint written by this version of femphase")
        if metadata.get("method", "fem") != method:
            raise SceneError("--method", method, f"{metadata.get('method')!r}, the method the run was started with")
        # the scene first: its message names the key that changed
        phase, phase_step, changes = resume_position(metadata["scene"], scene.to_dict(), metadata["time"])
        state, observers = load_checkpoint(checkpoint, simulation.domain)
        state.phase, state.phase_step = phase, phase_step
        simulation.restore_observers(observers)
        record = metadata["outputs"]
    else:
        state = scene.initial_state()
    trackers: list[Tracker] = [RunDirectory(directory, record, changes, argv, overwrite, sets)]
    if progress is not False:
        trackers.insert(0, ProgressBar(disable=None if progress is None else not progress))
    # here: both modules import this one
    from .guards import AccuracyGuard
    from .logs import StatusLog

    if status_interval is not None:
        trackers.append(StatusLog(status_interval))  # after RunDirectory: its first line goes to run.log
    trackers.append(AccuracyGuard())  # last: a frame is written before a strict stop
    with stop_on_signals() as stop:
        return simulation.run(state, trackers, initial_frame=not resume, stop=stop)
