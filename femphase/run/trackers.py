"""Trackers a caller composes into a run (py-pde style): the progress bar
(:class:`ProgressBar`), the periodic status line (:class:`StatusLog`) and frames kept in
memory (:class:`FrameRecorder`); the run directory's writer is
:class:`femphase.run.directory.RunDirectory`, the accuracy guard
:class:`femphase.run.guards.AccuracyGuard`.

femphase logs under the logger name ``femphase`` (:data:`LOGGER`) and configures nothing on
import (the package adds a NullHandler only). A run directory appends the log to
``run.log`` (:class:`femphase.io.rundir.RunLog`); ``femphase run`` adds a console handler on
stderr (:func:`femphase.io.console.console_handler`). From Python,
``logging.basicConfig(level=logging.INFO)`` shows the status lines of a :class:`StatusLog`:

    Simulation(scene).run(scene.initial_state(), [StatusLog(interval=10.0)])

A status line (level INFO) reads

    status: t=450 step=450/1800 phase=1:shear ms/step=3.12 substep=3.33 rejected=0 capped=0 windows=1 mean_dofs=2304 rss=118MiB peak=121MiB eta=4s

with t the simulated time (time units), step the steps done of the scene's total, the
phase (index:name), the mean wall time per step since the previous line (ms), under the
adaptive scheme the mean accepted substep since the previous line (time units; ``-``
when none was taken), the substeps rejected since, and the accepted ones whose size a
ceiling (the area mode's, the split repulsion's) set rather than the error estimate
(``capped``: when all are, the ceiling, not the tolerance, set the step); these three are absent for other schemes. Then
the number of windows (one per particle) and their mean size in dofs, the resident memory of the process
now (``rss``, /proc/self/statm; absent where there is no /proc) and its peak (``peak``,
resource.getrusage's ru_maxrss), in MiB, and the remaining wall time if the remaining
steps run at that rate (``eta``). The prefix says why the line was written: ``status``
(every ``interval`` seconds of wall time), ``start`` or ``resume`` (the run or segment
starts), ``phase K:NAME start`` and ``phase K:NAME end``.
"""

from __future__ import annotations

import logging
import os
import sys
import time as wallclock

import numpy as np

from femphase.analysis.observables import OBSERVABLES
from femphase.io.rundir import frame_time
from femphase.run.simulation import Frame, Simulation, Tracker
from femphase.state import State

__all__ = ["LOGGER", "FrameRecorder", "ProgressBar", "StatusLog", "format_duration", "memory_mib"]

#: The logger every femphase module logs to.
LOGGER = logging.getLogger("femphase")


def memory_mib() -> tuple[float | None, float | None]:
    """(resident memory now, peak resident memory) of this process in MiB. Now: from
    /proc/self/statm (resident pages × page size; None without /proc). Peak: from
    resource.getrusage(RUSAGE_SELF).ru_maxrss (KiB on Linux, bytes on macOS), at least
    now; None where the resource module is missing (Windows)."""
    try:
        with open("/proc/self/statm") as handle:
            now = int(handle.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        now = None
    try:
        import resource
    except ImportError:
        return now, None
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (2**20 if sys.platform == "darwin" else 2**10)
    return now, peak if now is None else max(peak, now)  # the kernel updates ru_maxrss lazily


def format_duration(seconds: float) -> str:
    """A wall time for people: "42s", "5m03s", "2h07m"."""
    seconds = round(seconds)
    if seconds < 60:
        return f"{seconds}s"
    if seconds < 3600:
        return f"{seconds // 60}m{seconds % 60:02d}s"
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m"


class StatusLog(Tracker):
    """Logs a status line (module docstring) every ``interval`` seconds of wall time and at
    the start and end of every phase: the progress of a batch job, which has no terminal
    for a progress bar. ``interval`` = 0 logs every step."""

    def __init__(self, interval: float = 30.0, logger: logging.Logger = LOGGER) -> None:
        if not interval >= 0:
            raise ValueError(f"StatusLog interval must be a number of seconds >= 0, not {interval!r}")
        self.interval, self.logger = interval, logger

    def start(self, simulation: Simulation, state: State) -> None:
        self.simulation = simulation
        self._mark(state)
        self.line("resume" if state.step > 0 else "start", state)

    def after_step(self, state: State) -> None:
        phases = self.simulation.scene.phases
        if state.phase_step == phases[state.phase].n_steps:  # the phase's last step (it advances after us)
            self.line(f"phase {self._phase(state.phase)} end", state)
            if state.phase + 1 < len(phases):
                self.line(f"phase {self._phase(state.phase + 1)} start", state, state.phase + 1)
        elif wallclock.monotonic() - self._since >= self.interval:
            self.line("status", state)

    def line(self, event: str, state: State, phase: int | None = None) -> None:
        """Log the status line of ``state`` now, prefixed by ``event``; ``phase``: the
        phase to name (default: the one under way, or the last when all are done)."""
        if not self.logger.isEnabledFor(logging.INFO):
            return
        simulation = self.simulation
        now = wallclock.monotonic()
        done, total = simulation.steps_done(state), simulation.total_steps()
        steps = state.step - self._since_step
        seconds_per_step = (now - self._since) / steps if steps > 0 else None
        phase = self._phase(min(state.phase, len(simulation.scene.phases) - 1) if phase is None else phase)
        dofs = sum(len(f) for f in state.fields) / max(state.n_particles, 1)
        rss, peak = memory_mib()
        parts = [f"t={state.time:.6g}", f"step={done}/{total}", f"phase={phase}",
                 f"ms/step={1e3 * seconds_per_step:.3g}" if seconds_per_step is not None else "ms/step=-"]
        parts += self._substeps(state)
        parts += [f"windows={state.n_particles}", f"mean_dofs={dofs:.0f}"]
        parts += [f"rss={rss:.0f}MiB"] if rss is not None else []
        parts += [f"peak={peak:.0f}MiB"] if peak is not None else []
        parts.append(f"eta={format_duration((total - done) * seconds_per_step)}" if seconds_per_step is not None
                     else "eta=-")
        self.logger.info("%s: %s", event, " ".join(parts))
        if steps > 0:  # the next rate is measured from here
            self._mark(state, now)

    def _substeps(self, state: State) -> list[str]:
        """``substep=``, ``rejected=`` and ``capped=`` (accepted substeps whose size the
        ceilings of the adaptive scheme set, not the error estimate) since the previous line, for schemes
        that count their substeps (``adaptive``: ``State.memory["adaptive_counts"]`` and
        ``["adaptive_phase_counts"]``); none for others."""
        counts = state.memory.get("adaptive_counts")
        if counts is None:
            return []
        accepted, rejected = (int(n) for n in counts - self._since_counts)
        substep = f"{(state.time - self._since_time) / accepted:.3g}" if accepted > 0 else "-"
        return [f"substep={substep}", f"rejected={rejected}", f"capped={self._capped(state) - self._since_capped}"]

    @staticmethod
    def _capped(state: State) -> int:
        per_phase = state.memory.get("adaptive_phase_counts")
        return int(per_phase[:, 2].sum()) if per_phase is not None and per_phase.shape[1] > 2 else 0

    def _mark(self, state: State, now: float | None = None) -> None:
        self._since, self._since_step = wallclock.monotonic() if now is None else now, state.step
        self._since_time = state.time
        self._since_counts = np.array(state.memory.get("adaptive_counts", np.zeros(2, dtype=np.int64)))
        self._since_capped = self._capped(state)

    def _phase(self, index: int) -> str:
        return f"{index}:{self.simulation.scene.phases[index].name}"


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
    """Keeps every frame's state and observables in memory (for scripts, tests, notebooks):
    those of the scene's ``output.observables``, registered ones included, as a run
    directory records them."""

    @property
    def needs(self) -> frozenset:
        return frozenset(OBSERVABLES.names())  # read when a run starts: observables registered by then

    def __init__(self) -> None:
        self.frames: list[Frame] = []

    def frame(self, frame: Frame) -> None:
        self.frames.append(Frame(frame.state.copy(), frame.phase, dict(frame.particle), dict(frame.globals)))

    def series(self, name: str, kind: str = "particle") -> np.ndarray:
        """(n_frames, N) array of a per-particle column (e.g. "elongation"), or with
        kind="global" (n_frames,) of a global one (e.g. "free_energy"). KeyError naming the
        columns recorded when ``name`` is none of them; ValueError for another ``kind``."""
        attribute = {"particle": "particle", "global": "globals"}
        if kind not in attribute:
            raise ValueError(f"kind = {kind!r} is invalid: 'particle' (per-particle columns) or 'global'")
        if not self.frames:
            raise KeyError(f"no {kind} column {name!r}: no frame recorded yet (run a Simulation with this recorder)")
        if name not in getattr(self.frames[0], attribute[kind]):
            other = "global" if kind == "particle" else "particle"
            hint = (f" ({name!r} is a {other} column: kind={other!r})"
                    if name in getattr(self.frames[0], attribute[other]) else "")
            recorded = ", ".join(sorted(getattr(self.frames[0], attribute[kind])))
            raise KeyError(f"no {kind} column {name!r}; recorded: {recorded}{hint}")
        return np.stack([np.asarray(getattr(f, attribute[kind])[name]) for f in self.frames])

    @property
    def times(self) -> np.ndarray:
        """The frames' times as the outputs give them (:func:`~femphase.io.rundir.frame_time`:
        12 significant digits, so ten steps of 0.1 are 1.0, as in particles.csv); each frame's
        ``state.time`` keeps the clock to the last bit."""
        return np.array([frame_time(f.state.time) for f in self.frames])
