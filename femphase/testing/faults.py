"""Kill a real ``femphase run`` at many points, resume it, and check that nothing was lost.

:func:`kill_and_resume` runs the command line in subprocesses and stops it again and again:

* with SIGKILL after 1–3 more frames, mid-step (what an out-of-memory kill or ``kill -9`` does);
* with SIGTERM or SIGINT after 1–3 more frames (``timeout``, Slurm, ``docker stop``, Ctrl-C:
  handled, the run stops after its current step with a checkpoint);
* with SIGKILL at a failpoint (:func:`femphase.io.files.failpoint`): half-way through a frame's
  CSV rows, between writing and renaming a field frame, the checkpoint, fields.xdmf or
  run.json,

and after each stop resumes with ``--resume`` (or starts again with ``--overwrite`` when no
checkpoint exists yet). :func:`identical_outputs` then compares the directory with an
uninterrupted run of the same scene: both CSVs and fields.xdmf byte for byte, every field
frame's arrays exactly, and the final checkpoint's fields exactly. Used by
``tests/test_kills.py`` and ``benchmarks/faults.py``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["KILLS", "SCENE", "campaign", "identical_outputs", "kill_and_resume", "run_uninterrupted"]

#: How the harness stops a run, in turn.
KILLS = ("SIGKILL", "failpoint:csv", "SIGTERM", "failpoint:fields", "SIGINT", "failpoint:checkpoint",
         "SIGKILL", "failpoint:fields.xdmf", "failpoint:run.json")

#: A small scene that runs long enough (a few seconds) to be killed many times: relaxation,
#: then shear, with the T1 counter's running state in every checkpoint.
SCENE = """
name = "kill test"
[domain]
Lx = 48.0
Ly = 48.0
[particles]
layout = "random"
N = 6
seed = 2
[output]
observables = ["order"]
[[phases]]
name = "relax"
duration = 100.0
dt = 1.0
frame_interval = 10.0
[[phases]]
name = "shear"
duration = 500.0
dt = 1.0
frame_interval = 10.0
flow = { type = "shear", rate = 0.4 }
"""


def _command(scene: Path, directory: Path, *flags: str) -> list[str]:
    return [sys.executable, "-m", "femphase.cli", "run", str(scene), "-o", str(directory), "-q", *flags]


def _environment(failpoint: str | None = None) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    env.pop("FEMPHASE_FAILPOINT", None)
    if failpoint:
        env["FEMPHASE_FAILPOINT"] = failpoint
    return env


def run_uninterrupted(scene: Path, directory: Path) -> None:
    subprocess.run(_command(scene, directory), env=_environment(), check=True, capture_output=True)


def kill_and_resume(scene: Path, directory: Path, kills: int, seed: int = 0, timeout: float = 900.0,
                    first: int = 0) -> list[dict]:
    """Stop a run of ``scene`` into ``directory`` ``kills`` times (see the module
    docstring), resuming after each stop, then let it finish; the stops cycle through
    :data:`KILLS` from its entry ``first``. Returns one record per attempt: how (``kind``),
    the exit code, whether the next start had to be a fresh one, and ``stopped``: False for
    the last attempt if the run finished before its stop came (a failpoint later than the
    run's last write, or a signal after its end).

    A signal's stop point is chosen by progress, not by wall time: it is sent as soon as the
    run has written 1–3 more frames (drawn from ``seed``) since its start, so a loaded machine
    changes when a stop comes, never whether it lands inside the run. ``timeout`` (seconds per
    attempt) only guards against a hung run and fails loudly."""
    rng = np.random.default_rng(seed)
    events: list[dict] = []
    flags: tuple[str, ...] = ()
    for k in range(kills):
        kind = KILLS[(first + k) % len(KILLS)]
        failpoint = f"{kind.split(':')[1]}:{int(rng.integers(1, 4))}" if kind.startswith("failpoint") else None
        process = subprocess.Popen(_command(scene, directory, *flags), env=_environment(failpoint),
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        if failpoint is None:
            _wait_for_frames(directory, process, frames=int(rng.integers(1, 4)), timeout=timeout)
            if process.poll() is None:
                process.send_signal(getattr(signal, kind))
        try:
            _, stderr = process.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            raise
        resumable = (directory / "checkpoint.h5").is_file()
        events.append({"kind": failpoint and f"failpoint {failpoint}" or kind, "exit_code": process.returncode,
                       "resumable": resumable, "status": _status(directory),
                       "stderr": stderr.decode(errors="replace")[-400:], "stopped": process.returncode != 0})
        if process.returncode == 0:
            break  # it finished before the stop: nothing more to interrupt
        flags = ("--resume",) if resumable else ("--overwrite",)
    final = subprocess.run(_command(scene, directory, *flags) if events[-1]["exit_code"] != 0 else ["true"],
                           env=_environment(), capture_output=True, timeout=timeout)
    if final.returncode != 0:
        raise RuntimeError(f"the final resume failed ({final.returncode}): {final.stderr.decode()[-2000:]}")
    return events


def _status(directory: Path) -> str | None:
    import json

    try:
        return json.loads((directory / "run.json").read_text()).get("status")
    except (OSError, ValueError):
        return None


def campaign(scene_text: str, workdir: Path, kills: int, seed: int = 0) -> dict:
    """Kill runs of ``scene_text`` at least ``kills`` times in all (a new run directory
    whenever one finishes first), and compare each with an uninterrupted run. Returns the
    counts and every stop."""
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    scene = workdir / "scene.toml"
    scene.write_text(scene_text)
    reference = workdir / "uninterrupted"
    run_uninterrupted(scene, reference)
    events, differences, runs = [], [], 0
    stops = 0
    while stops < kills:
        if runs >= 4 * kills:
            raise RuntimeError(f"{runs} runs finished before their stops came; the scene is too short to interrupt")
        directory = workdir / f"killed-{runs}"
        # a stop that came too late (the run had finished) is tried again in the next run
        events += kill_and_resume(scene, directory, kills - stops, seed=seed + runs, first=stops)
        stops = sum(event["stopped"] for event in events)
        differences += [f"{directory.name}: {d}" for d in identical_outputs(reference, directory)]
        runs += 1
    return {"kill_points": stops, "runs": runs, "resumes_bit_identical": runs - len({d.split(":")[0] for d in differences}),
            "differences": differences, "events": events}


def _wait_for_frames(directory: Path, process: subprocess.Popen, frames: int, timeout: float) -> None:
    """Until the run has a checkpoint and ``frames`` more rows in global.csv than at its
    start, or has ended. Polls every 10 ms: the stop lands within a fraction of a frame."""
    path = directory / "global.csv"

    def rows() -> int:
        try:
            return path.read_bytes().count(b"\n")
        except OSError:
            return 0

    start = rows()
    deadline = time.monotonic() + timeout
    while process.poll() is None:
        if rows() >= start + frames and (directory / "checkpoint.h5").exists():
            return
        if time.monotonic() > deadline:
            process.kill()
            raise RuntimeError(f"the run in {directory} wrote no {frames} frames within {timeout} s")
        time.sleep(0.01)


def identical_outputs(a: Path, b: Path) -> list[str]:
    """What differs between two run directories' outputs (empty: identical)."""
    import h5py

    differences = []
    for name in ("particles.csv", "global.csv", "fields.xdmf", "scene.toml"):
        if (a / name).read_bytes() != (b / name).read_bytes():
            differences.append(name)
    frames_a = sorted(p.name for p in (a / "fields").glob("frame_*.h5"))
    frames_b = sorted(p.name for p in (b / "fields").glob("frame_*.h5"))
    if frames_a != frames_b:
        differences.append(f"field frames: {len(frames_a)} against {len(frames_b)}")
    for name in set(frames_a) & set(frames_b):
        with h5py.File(a / "fields" / name, "r") as fa, h5py.File(b / "fields" / name, "r") as fb:
            if set(fa) != set(fb) or any(not np.array_equal(fa[k][()], fb[k][()]) for k in fa):
                differences.append(f"fields/{name}")
    with h5py.File(a / "checkpoint.h5", "r") as ca, h5py.File(b / "checkpoint.h5", "r") as cb:
        for key in ("values", "windows", "radii"):
            if not np.array_equal(ca[key][()], cb[key][()]):
                differences.append(f"checkpoint {key}")
    return differences
