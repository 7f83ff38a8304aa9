"""Running a scene into a run directory, what ``femphase run`` does (:func:`run_scene`):
the checks before anything is written, the resume from a checkpoint, the trackers, and
stopping cleanly on SIGINT/SIGTERM."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from femphase.errors import SceneError
from femphase.io.checkpoints import load_checkpoint, read_checkpoint_metadata
from femphase.io.files import output_directory
from femphase.io.rundir import CHECKPOINT, prepare_directory, resume_position
from femphase.model.energy import FreeEnergy
from femphase.run.directory import RunDirectory
from femphase.run.guards import AccuracyGuard
from femphase.run.simulation import METHODS, Simulation, Tracker
from femphase.run.trackers import ProgressBar, StatusLog
from femphase.scene import Scene, check_numerics, placed_count
from femphase.state import State

__all__ = ["check_resumed_method", "run_scene", "stop_on_signals"]


def check_resumed_method(directory: str | Path, method: str) -> None:
    """SceneError (key ``--method``) when the run in ``directory`` was started with another
    method ("fem" or "fd"; a scene whose scheme is "fd-heun" runs "fd"). Nothing when the
    directory holds no checkpoint: what that means is :func:`prepare_directory`'s to say."""
    checkpoint = Path(directory) / CHECKPOINT
    if checkpoint.is_file():
        recorded = read_checkpoint_metadata(checkpoint).get("method", "fem")
        if recorded != method:
            raise SceneError("--method", method, f"{recorded!r}, the method the run was started with")


@contextmanager
def stop_on_signals() -> Iterator[Callable[[], int | None]]:
    """While active, SIGINT and SIGTERM (what Ctrl-C, ``timeout``, Slurm and ``docker stop``
    send) ask the run to stop after the current step: yields the ``stop`` callable of
    :meth:`femphase.run.simulation.Simulation.run`. A second signal interrupts at once. Outside the main thread
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
              sets: list[str] | None = None, status_interval: float | None = 30.0,
              energy: FreeEnergy | None = None) -> State:
    """Run a scene into a run directory (what ``femphase run`` does), on any domain.

    A directory that already holds a run is refused unless ``resume`` (continue from its
    checkpoint; the scene may change only compatibly, :func:`femphase.io.rundir.resume_position`)
    or ``overwrite``, and so is a directory another process is running in (its lock,
    :func:`femphase.io.rundir.prepare_directory`, held until the run ends). Nothing in the
    directory is touched before every check has passed.
    ``progress``: the tqdm bar (None: only on a terminal); ``argv`` and ``sets``: the command
    line and its ``--set`` assignments, for run.json; ``status_interval``: seconds of wall
    time between status lines in the log (:class:`femphase.run.trackers.StatusLog`; None: none);
    ``energy``: the free energy, if not the paper's (:class:`~femphase.run.simulation.Simulation`;
    a resumed run needs the same terms, whose columns global.csv holds)."""
    directory = output_directory(directory)  # "" is refused here, before Path makes it "."
    simulation = Simulation(scene, method, energy)
    # a method given here is named before the scene's checks made for it; a scene's own scheme
    # ("fd-heun") after them, which name its key
    forced = METHODS[method] is not None
    if resume and forced:
        check_resumed_method(directory, simulation.method)
    check_numerics(scene, METHODS[method])  # what the first step would refuse, refused before any write
    if resume and not forced:
        check_resumed_method(directory, simulation.method)
    lock = prepare_directory(directory, resume=resume, overwrite=overwrite)
    try:
        record, changes = None, []
        if resume:
            checkpoint = directory / CHECKPOINT
            metadata = read_checkpoint_metadata(checkpoint)
            if not {"scene", "outputs", "time"} <= set(metadata):
                raise SceneError("--resume", str(checkpoint), "a checkpoint written by this version of femphase")
            # the scene first: its message names the key that changed. A layout that places its
            # particles without N is compared by its centres (checkpoints recorded the default N)
            saved, current = metadata["scene"], simulation.settings()
            for settings in (saved, current):
                if placed_count(settings.get("particles", {})) is not None:
                    settings["particles"].pop("N", None)
            # femphase ≤ 0.2.0 wrote a mesh's median edge as domain.h where the scene gave none
            domain = simulation.domain
            if (domain.kind == "mesh" and "h" not in current["domain"]
                    and saved.get("domain", {}).get("h") == domain.median_edge):
                saved["domain"].pop("h")
            try:
                phase, phase_step, changes = resume_position(saved, current, metadata["time"])
            except SceneError as exc:  # most often an earlier --set the resume's command left out
                raise SceneError(exc.key, exc.value, f"{exc.valid}. A resume reads the scene file again with its "
                                 "own --set assignments only: the run's earlier ones are in its run.json "
                                 "(each segment's \"set\")") from None
            state, observers = load_checkpoint(checkpoint, simulation.domain)
            state.phase, state.phase_step = phase, phase_step
            simulation.restore_observers(observers)
            record = metadata["outputs"]
        else:
            state = scene.initial_state()
        trackers: list[Tracker] = [RunDirectory(directory, record, changes, argv, overwrite, sets, lock)]
        if progress is not False:
            trackers.insert(0, ProgressBar(disable=None if progress is None else not progress))
        if status_interval is not None:
            trackers.append(StatusLog(status_interval))  # after RunDirectory: its first line goes to run.log
        trackers.append(AccuracyGuard())  # last: a frame is written before a strict stop
        with stop_on_signals() as stop:
            return simulation.run(state, trackers, initial_frame=not resume, stop=stop)
    except BaseException as exc:
        # what a stopped run can say it kept (femphase.cli): its checkpoint, its frames only, or
        # no checkpoint yet (stopped before its first)
        exc.kept = ("frames" if not scene.output.checkpoint else
                    "checkpoint" if (directory / CHECKPOINT).is_file() else "nothing")
        raise
    finally:
        lock.release()
