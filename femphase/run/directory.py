"""The tracker that writes a run directory (:mod:`femphase.io.rundir`): every frame's rows
and field frame, then its checkpoint; run.json's status; the femphase log into run.log."""

from __future__ import annotations

import logging
import shlex
import warnings
from pathlib import Path

import numpy as np

from femphase import __version__
from femphase.analysis.observables import OBSERVABLES
from femphase.errors import Interrupted, StopRun
from femphase.io.checkpoints import save_checkpoint
from femphase.io.fields import point_data
from femphase.io.files import FileLock, atomic_write, output_directory
from femphase.io.provenance import provenance
from femphase.io.rundir import CHECKPOINT, Outputs, RunLog, Status, frame_time, prepare_directory
from femphase.run.simulation import Frame, Simulation, Tracker
from femphase.run.trackers import LOGGER
from femphase.state import State
from femphase.tomlio import to_toml

__all__ = ["RunDirectory"]


class RunDirectory(Tracker):
    """Writes a run directory (:mod:`femphase.io.rundir`): appends every frame's rows and field
    frame, then its checkpoint; keeps run.json's status current; appends the femphase
    logger's records to run.log while it runs (:class:`femphase.io.rundir.RunLog`).

    ``resume_from``: the checkpoint's record of the outputs (a resumed run cuts them back to
    it); ``changes``: what the resumed scene changed; ``argv``: the command line (without
    the program) and ``sets``: its ``--set`` assignments (run.json's segment records all
    three); ``overwrite``: replace a run already in the directory (else it is refused,
    :func:`femphase.io.rundir.prepare_directory`); ``lock``: the directory's lock where the
    caller prepared the directory and holds it (else :meth:`start` prepares it and takes the
    lock, and :meth:`finish` releases it)."""

    def __init__(self, directory: str | Path, resume_from: dict | None = None, changes: list[str] | None = None,
                 argv: list[str] | None = None, overwrite: bool = False, sets: list[str] | None = None,
                 lock: FileLock | None = None) -> None:
        self.directory = output_directory(directory)
        self.resume_from, self.changes, self.argv, self.overwrite = resume_from, list(changes or []), argv, overwrite
        self.sets = list(sets or [])
        self.needs = frozenset(OBSERVABLES.names())
        self.lock, self._owns_lock = lock, lock is None

    def start(self, simulation: Simulation, state: State) -> None:
        scene = simulation.scene
        self.simulation = simulation
        if self._owns_lock:
            self.lock = prepare_directory(self.directory, resume=self.resume_from is not None, overwrite=self.overwrite)
        particle_columns, global_columns = simulation.columns()
        self.outputs = Outputs(self.directory, particle_columns, global_columns, scene.output.fields)
        self.particle_columns, self.global_columns = particle_columns, global_columns
        mesh = simulation.domain.mesh
        if self.resume_from is None:
            self.outputs.start_new(mesh)
        else:
            self.outputs.start_from(self.resume_from, mesh)  # checks every file before it cuts any
        previous = None
        if self.resume_from is not None:
            previous = Status.read(self.directory)
            if previous is None:
                warnings.warn(f"{self.directory / 'run.json'} is missing or not JSON: the resumed run writes a new "
                              "one, without the earlier segments' history (start, hosts, CPU times); the data and "
                              "the checkpoint are intact", stacklevel=2)
        #: the resolved scene as it runs: scene.toml, run.json's settings and every checkpoint's
        self.settings = simulation.settings()
        atomic_write(self.directory / "scene.toml", to_toml(self.settings))
        self.status = Status(self.directory, {
            "femphase_version": __version__, "method": simulation.method, "scene": scene.name,
            "settings": self.settings, "domain": simulation.domain.describe(),
        }, previous)
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
        self._report_changes()

    def _report_changes(self) -> None:
        """The resumed scene's changes, into run.log and onto the console: numerics as a
        warning (a resume takes the scene and ``--set`` given now, and an earlier ``--set``
        not given again is dropped without a word otherwise), the rest (durations, frames,
        later phases) as information."""
        numerics = [change for change in self.changes if change.startswith("numerics.")]
        if numerics:
            LOGGER.warning("resumed with numerics other than the checkpoint's: %s (give an earlier --set again to "
                           "keep its value)", "; ".join(numerics))
        others = [change for change in self.changes if not change.startswith("numerics.")]
        if others:
            LOGGER.info("resumed with changes: %s", "; ".join(others))

    def frame(self, frame: Frame) -> None:
        state = frame.state
        time = frame_time(state.time)
        columns = np.column_stack([np.full(state.n_particles, time), np.arange(state.n_particles)]
                                  + [np.asarray(frame.particle[c], dtype=float) for c in self.particle_columns])
        self.outputs.append_rows("particles.csv", ([row[0], int(row[1]), *row[2:]] for row in columns.tolist()))
        self.outputs.append_rows("global.csv", [[time, state.step] + [frame.globals[c] for c in self.global_columns]])
        output = self.simulation.scene.output
        if output.fields:
            self.outputs.append_fields(time, point_data(state, output.per_particle_fields), self.simulation.domain.mesh)
        if output.checkpoint:
            self._checkpoint(state)
        self.status.update(time=time, steps=state.step, **self._substeps(state))

    def _substeps(self, state: State) -> dict:
        """run.json's ``substeps``: per phase begun, the accepted and rejected substeps of a
        scheme that counts them, and the accepted ones whose size the area-mode ceiling set
        (``adaptive``: ``State.memory["adaptive_phase_counts"]``, checkpointed, so a resumed
        run's counts continue); none for other schemes."""
        counts = state.memory.get("adaptive_phase_counts")
        if counts is None:
            return {}
        phases = self.simulation.scene.phases
        keys = ("accepted", "rejected", "capped")
        return {"substeps": [{"phase": k, "name": phases[k].name, **dict(zip(keys, map(int, row)))}
                             for k, row in enumerate(counts.tolist()) if k < len(phases)]}

    def _checkpoint(self, state: State) -> None:
        save_checkpoint(self.directory / CHECKPOINT, state, self.simulation.observer_state(), {
            "scene": self.settings, "outputs": self.outputs.record(),
            "method": self.simulation.method, "time": state.time,
        })

    def finish(self, state: State, error: Exception | None) -> None:
        if error is None:
            status, message, level = "completed", "", logging.INFO
        elif isinstance(error, StopRun):  # a tracker's end: resumable to the scene's end
            status, message, level = "interrupted", f"stopped by a tracker: {error}", logging.INFO
        elif isinstance(error, (Interrupted, KeyboardInterrupt)):
            status, message, level = "interrupted", str(error) or "interrupted (KeyboardInterrupt)", logging.WARNING
        else:
            status, message, level = "failed", str(error) or type(error).__name__, logging.ERROR
        try:
            if isinstance(error, (Interrupted, StopRun)) and self.simulation.scene.output.checkpoint:
                self._checkpoint(state)  # a consistent state between two steps: keep it
            self.outputs.close()
            self.status.update(status=status, message=message, time=frame_time(state.time), steps=state.step,
                               steps_this_segment=state.step - self.first_step, **self._substeps(state))
        finally:  # the logger must not keep writing into this directory
            segment = self.status.data["segments"][-1]
            self.log.close(level, f"=== segment {len(self.status.data['segments'])} {status} after step {state.step} "
                                  f"(t = {state.time:g}), {segment['wall_time_s']:.1f} s wall time"
                                  + (f": {message}" if message else "") + " ===")
            if self._owns_lock:
                self.lock.release()
