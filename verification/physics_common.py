"""Shared helpers of the physics reproductions (``verification/physics_*.py``).

The reproductions run long simulations, so every run is resumable and cached:

* a run lives in ``verification/runs/<name>/`` (a femphase run directory, gitignored; the
  environment variable ``FEMPHASE_VERIFICATION_RUNS`` names another directory, e.g. for a
  rerun that must not reuse the runs there);
* :func:`ensure_run` skips a run that already reached the end of its scene, resumes one
  that was interrupted (from its checkpoint) and extends one whose scene got longer;
* runs that share a relaxation start from one relaxed checkpoint (``branch_from``), so
  that e.g. six shear rates on one lattice relax it only once;
* :func:`cached` keeps each run's analysed result as JSON next to it, so that re-running a
  script only analyses what is new.

Conventions: times in solver time units, angles in radians, γ̇ ("rate") the wall velocity
of the shear u = γ̇ y/Ly (docs/model.md).
"""

from __future__ import annotations

import json
import os
import shutil
import time as wallclock
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from femphase.io.checkpoints import load_checkpoint, read_checkpoint_metadata  # noqa: E402
from femphase.io.files import write_json
from femphase.io.rundir import resume_position  # noqa: E402
from femphase.scene import Scene, load_scene  # noqa: E402
from femphase.io.rundir import CHECKPOINT  # noqa: E402
from femphase.run.simulation import Simulation  # noqa: E402
from femphase.run.directory import RunDirectory
from femphase.run.runner import run_scene

REPO = Path(__file__).resolve().parent.parent
EXAMPLES = REPO / "examples"
RUNS = Path(os.environ.get("FEMPHASE_VERIFICATION_RUNS", REPO / "verification" / "runs"))
RESULTS = REPO / "verification" / "results"


#: The scheme and steps the stored results were computed with: the first-order scheme at
#: dt = 1 (the examples run the adaptive scheme at dt = 10).
#: A caller's own assignments come after these and win.
FIRST_ORDER = ['numerics.scheme="euler"', "phases.0.dt=1.0", "phases.1.dt=1.0"]


def example_scene(name: str, assignments: list[str]) -> Scene:
    """``examples/<name>.toml`` with :data:`FIRST_ORDER` and then ``--set``-style
    assignments applied."""
    return load_scene(EXAMPLES / f"{name}.toml", FIRST_ORDER + list(assignments))


def is_complete(directory: Path, scene: Scene) -> bool:
    """Whether `directory` holds a finished run of all of `scene`'s steps."""
    info = directory / "run.json"
    if not info.exists():
        return False
    run = json.loads(info.read_text())
    total = sum(p.n_steps for p in scene.phases)
    return run.get("status") == "completed" and run.get("steps") == total


def _continue(scene: Scene, directory: Path, method: str) -> None:
    """Continue the run in ``directory`` from its checkpoint under ``scene`` with ``method``:
    what ``femphase run --resume`` does (:func:`femphase.run.runner.run_scene`), except that
    the method may differ from the checkpoint's, so that a finite-difference branch can start
    from a relaxation done with FEM."""
    checkpoint = directory / CHECKPOINT
    metadata = read_checkpoint_metadata(checkpoint)
    simulation = Simulation(scene, method)
    state, observers = load_checkpoint(checkpoint, simulation.domain)
    state.phase, state.phase_step, changes = resume_position(metadata["scene"], scene.to_dict(), state.time)
    simulation.restore_observers(observers)
    simulation.run(state, [RunDirectory(directory, metadata["outputs"], changes)], initial_frame=False)


def ensure_run(scene: Scene, directory: Path, *, branch_from: Path | None = None, log=print,
               method: str = "fem") -> Path:
    """Run `scene` into `directory` unless it is already complete; returns `directory`.

    An interrupted run resumes from its checkpoint; a complete run whose scene has since
    grown longer (a longer last phase) continues to the new end.  With `branch_from`, a new
    run starts from the relaxed state in that directory (which must hold the run of the
    scene's first phase alone, see :func:`ensure_relaxation`): its checkpoint and CSV files
    are copied over and the remaining phases run from there, with ``method`` ("fem" or "fd").
    A directory with outputs but no checkpoint (a run that failed before its first frame) is
    started again. The wall time of every session is appended to ``sessions.json``.
    """
    directory = Path(directory)
    if is_complete(directory, scene):
        return directory
    checkpoint = directory / CHECKPOINT
    if not checkpoint.exists() and branch_from is not None:
        directory.mkdir(parents=True, exist_ok=True)
        for name in (CHECKPOINT, "particles.csv", "global.csv"):
            shutil.copy2(Path(branch_from) / name, directory / name)
    started = wallclock.perf_counter()
    if checkpoint.exists():
        log(f"  {directory.name}: continuing from t = {load_checkpoint(checkpoint, scene.domain)[0].time:g}")
        _continue(scene, directory, method)
    else:
        log(f"  {directory.name}: starting")
        run_scene(scene, directory, overwrite=True, method=method, progress=False)
    sessions = directory / "sessions.json"
    previous = json.loads(sessions.read_text()) if sessions.exists() else []
    sessions.write_text(json.dumps(previous + [{"wall_s": wallclock.perf_counter() - started}], indent=1))
    return directory


def ensure_relaxation(scene: Scene, directory: Path, log=print) -> Path:
    """Run the first phase of `scene` alone (the relaxation shared by its branches)."""
    return ensure_run(replace(scene, phases=scene.phases[:1]), directory, log=log)


def cached(path: Path, compute: Callable[[], dict], key: dict | None = None) -> dict:
    """The JSON result at `path` if it exists (and was made with the same `key`), else
    ``compute()``, written to `path` with the key under "key"."""
    path = Path(path)
    if path.exists():
        stored = json.loads(path.read_text())
        if key is None or stored.get("key") == json.loads(json.dumps(key)):
            return stored
    result = compute()
    if key is not None:
        result = {"key": key, **result}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, result)
    return json.loads(path.read_text())


def wall_seconds(directory: Path) -> float:
    """Wall time spent on a run over all its sessions (NaN if none was logged)."""
    sessions = Path(directory) / "sessions.json"
    if sessions.exists():
        return float(sum(s["wall_s"] for s in json.loads(sessions.read_text())))
    info = Path(directory) / "run.json"
    if not info.exists():
        return float("nan")
    segments = json.loads(info.read_text()).get("segments", [])
    return float(sum(s.get("wall_time_s", 0.0) for s in segments)) if segments else float("nan")


def fmt(value: float, uncertainty: float | None = None, digits: int = 3) -> str:
    """A number for a Markdown table, with its uncertainty when given."""
    if value is None or not np.isfinite(value):
        return "—"
    if uncertainty is None or not np.isfinite(uncertainty):
        return f"{value:.{digits}g}"
    return f"{value:.{digits}g} ± {uncertainty:.2g}"
