"""Step time of this tree against another femphase tree (the code before a redesign), interleaved.

    python benchmarks/redesign_step_time.py --old /path/to/old/tree [--runs 4] [--sessions 3]

Both trees' own ``benchmarks/step_time.py`` measure: its ``time_steps`` (the N = 100 lattice,
h = 1, dt = 1, shear γ̇ = 0.1487, relaxed 100 steps, first shear step untimed, then 300
windowed steps; the full mesh: 20 relaxation steps, then 10 steps) runs unchanged in a
subprocess whose ``femphase`` is imported from that tree (checked). Nothing is written into
either tree except ``results/redesign_step_time.json`` of this one. On a shared machine the
absolute times drift by tens of percent within minutes, so only same-time ratios count. Two
protocols, one process at a time:

* runs: whole ``time_steps`` runs in fresh subprocesses, in blocks old, new, new, old
  (``--runs`` blocks); the ratio pairs each new run with the old run next to it.
* batches: one worker subprocess per tree prepares exactly as ``time_steps`` does, then the
  two take turns (old, new, new, old, …) running batches of ``--batch`` timed steps while
  the other waits (blocked on a pipe, using no CPU); the state of both advances through the
  same steps. The ratio of each batch pair (median step of the new batch over that of the
  adjacent old batch) sees the same machine load within a fraction of a second.
  ``--sessions`` fresh pairs of workers.

Each step is timed as step_time.py times it (wall clock, ``perf_counter``) and also in CPU
time of the worker process (``process_time``, read at the same two instants).

``--default-scheme`` times the default scheme instead: both trees' ``step_time.per_time_unit``
(CPU ms per simulated time unit of the lattice's shear at outer step ``FRAME``, after the
same relaxation) in whole runs only, blocks old, new, new, old; the trees must both have
it (session 5 on), or the old tree must predate issue 12 (489f515, the code of the day the
issue was filed): then its default, first order at dt = 1, is timed through its ``time_steps``
(the same relaxation, then ``--shear-time`` steps of dt = 1, each in CPU time). A tree
with ``step_time.EXAMPLE_CALL`` (session 12 on) takes its steps in calls of that many, as
the examples' runs do (``--steps-per-call`` another number). Written to ``results/default_scheme_step_time.json`` (``--output``).
With ``--random-rate R``: the random packing of ``step_time.random_packing`` (the trees must
have it: session 6 on) sheared at R instead of the lattice.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
NEW_TREE = HERE.parent
RESULTS = HERE / "results"
MODES = {"windows": True, "full_mesh": False}


# -- the worker (runs inside a subprocess on one tree) ------------------------------------------
class _Clock:
    """Stands in for step_time's ``time`` module: ``perf_counter`` also records process_time,
    and before the first step of every batch it reports and waits for the controller."""

    def __init__(self, batch: int, gated: bool) -> None:
        self.batch, self.gated, self.calls, self.cpu, self.wall = batch, gated, 0, [], []

    def perf_counter(self) -> float:
        if self.gated and self.calls % (2 * self.batch) == 0:  # a step's start, first of a batch
            print("ready", flush=True)
            if sys.stdin.readline().strip() != "go":
                raise SystemExit(0)
        self.calls += 1
        self.cpu.append(time.process_time())
        self.wall.append(time.perf_counter())
        return self.wall[-1]

    def per_step_ms(self, samples: list[float]) -> np.ndarray:
        """Step durations (ms) from the (start, end) readings of every step."""
        return np.diff(np.array(samples).reshape(-1, 2), axis=1)[:, 0] * 1e3

    def __getattr__(self, name: str):
        return getattr(time, name)


def _tree_step_time(tree: str):
    """That tree's benchmarks/step_time.py module (its common pins BLAS), and its femphase path."""
    sys.path[0] = os.path.join(tree, "benchmarks")  # not this script's directory
    import step_time

    import femphase

    for module in (femphase, step_time):
        assert module.__file__.startswith(tree + os.sep), (module.__file__, tree)
    return step_time, femphase.__file__


class _CPUClock:
    """Stands in for the ``time`` module of a pre-issue-12 step_time.py: its ``perf_counter``
    reads the process's CPU time."""

    def perf_counter(self) -> float:
        return time.process_time()

    def __getattr__(self, name: str):
        return getattr(time, name)


def default_worker(tree: str, shear_time: float, random_rate: float | None, steps_per_call: int | None) -> None:
    step_time, path = _tree_step_time(tree)
    if not hasattr(step_time, "per_time_unit"):
        # Before issue 12 the default was first order at dt = 1, and step_time.time_steps timed
        # exactly the default's steps after the same 100-step relaxation.
        if random_rate is not None:
            raise SystemExit(f"{tree} predates issue 12 and has no random packing benchmark")
        step_time.time = _CPUClock()
        row = step_time.time_steps(True, round(shear_time))
        ms = row["mean_ms"] * row["steps"] / shear_time
    elif random_rate is None and hasattr(step_time, "EXAMPLE_CALL"):  # session 12 on: calls of several steps
        ms = step_time.per_time_unit(step_time.FRAME, shear_time, steps_per_call or step_time.EXAMPLE_CALL)
    elif random_rate is None:
        ms = step_time.per_time_unit(step_time.FRAME, shear_time)
    else:
        ms = step_time.random_packing([random_rate], shear_time)["ms_per_time_unit"][str(random_rate)]
    print(json.dumps({"tree": tree, "femphase": path, "ms_per_time_unit": ms}), flush=True)


def worker(tree: str, steps: dict, batch: dict, gated: bool) -> None:
    step_time, path = _tree_step_time(tree)
    out = {"tree": tree, "femphase": path}
    for mode, windows in MODES.items():
        clock = step_time.time = _Clock(batch[mode], gated)
        row = step_time.time_steps(windows, steps[mode])
        wall, cpu = clock.per_step_ms(clock.wall), clock.per_step_ms(clock.cpu)
        assert wall.size == steps[mode] and np.isclose(np.median(wall), row["median_ms"])
        row.update(cpu_median_ms=float(np.median(cpu)), cpu_ms=cpu.tolist(), wall_ms=wall.tolist())
        out[mode] = row
    if gated:
        print("ready", flush=True)  # the last batch is done
    print(json.dumps(out), flush=True)


# -- the controller ----------------------------------------------------------------------------
def _env(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONDONTWRITEBYTECODE="1")
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = "1"
    return env


def _command(tree: Path, args, gated: bool) -> list[str]:
    return [sys.executable, str(Path(__file__).resolve()), "--worker", str(tree), "--steps", str(args.steps),
            "--full-steps", str(args.full_steps), "--batch", str(args.batch), "--full-batch", str(args.full_batch),
            "--shear-time", str(args.shear_time)] \
        + (["--gated"] if gated else []) + (["--default-scheme"] if args.default_scheme else []) \
        + ([] if args.random_rate is None else ["--random-rate", str(args.random_rate)]) \
        + ([] if args.steps_per_call is None else ["--steps-per-call", str(args.steps_per_call)])


def whole_run(tree: Path, args) -> dict:
    done = subprocess.run(_command(tree, args, False), cwd=tree, env=_env(tree), capture_output=True, text=True,
                          check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


class Worker:
    def __init__(self, tree: Path, args) -> None:
        self.process = subprocess.Popen(_command(tree, args, True), cwd=tree, env=_env(tree), text=True,
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.wait_ready()  # set-up (relaxation, factorisations) done

    def wait_ready(self) -> None:
        line = self.process.stdout.readline().strip()
        if line != "ready":
            raise RuntimeError(f"worker said {line!r}")

    def batch(self) -> None:
        """Run one batch (its steps are timed inside the worker), and wait for it."""
        self.process.stdin.write("go\n")
        self.process.stdin.flush()
        self.wait_ready()

    def result(self) -> dict:
        out = json.loads(self.process.stdout.readline())
        self.process.wait()
        return out


def batch_session(old: Path, new: Path, args) -> dict:
    """Two workers taking turns, batch b of the old tree next to batch b of the new one.
    (The last windowed batch also runs the full-mesh set-up, untimed, before its "ready".)"""
    workers = {"old": Worker(old, args), "new": Worker(new, args)}
    for n, size in ((args.steps, args.batch), (args.full_steps, args.full_batch)):
        for b in range(-(-n // size)):
            for name in (("old", "new") if b % 2 == 0 else ("new", "old")):
                workers[name].batch()
    return {name: w.result() for name, w in workers.items()}


def _batch_ratios(session: dict, mode: str, size: int, clock: str = "cpu") -> list[float]:
    """Median step of each new batch over that of the old batch run next to it."""
    old = np.array(session["old"][mode][f"{clock}_ms"])
    new = np.array(session["new"][mode][f"{clock}_ms"])
    return [float(np.median(new[i:i + size]) / np.median(old[i:i + size])) for i in range(0, old.size, size)]


def tree_version(tree: Path) -> dict:
    """The tree's git commit and the files of its femphase/ that differ from it (None outside git)."""
    def git(*args: str) -> str | None:
        done = subprocess.run(["git", "-C", str(tree), *args], capture_output=True, text=True, check=False)
        return done.stdout.strip() if done.returncode == 0 else None
    commit = git("rev-parse", "--short", "HEAD")
    dirty = git("status", "--porcelain", "--", "femphase")
    return {"commit": commit, "femphase_modified": None if commit is None else dirty.splitlines()}


def summary(values) -> dict:
    values = np.asarray(values, dtype=float)
    return {"median": float(np.median(values)), "q25": float(np.percentile(values, 25)),
            "q75": float(np.percentile(values, 75)), "min": float(values.min()), "max": float(values.max()),
            "n": int(values.size)}


def pair_ratios(values: list[float]) -> list[float]:
    """new/old of each new run and the old run next to it, for runs in blocks old, new, new, old."""
    pairs = []
    for b in range(0, len(values), 4):
        o1, n1, n2, o2 = values[b:b + 4]
        pairs += [n1 / o1, n2 / o2]
    return pairs


def default_scheme_runs(old: Path, new: Path, args) -> None:
    """The ``--default-scheme`` protocol (module docstring)."""
    runs = []
    for block in range(args.runs):
        for name in ("old", "new", "new", "old"):
            row = whole_run(old if name == "old" else new, args)
            runs.append({"which": name, **row})
            print(f"run {name}: {row['ms_per_time_unit']:.3f} CPU ms per time unit", flush=True)
    ms = {name: [r["ms_per_time_unit"] for r in runs if r["which"] == name] for name in ("old", "new")}
    pairs = pair_ratios([r["ms_per_time_unit"] for r in runs])
    result = {"old_tree": str(old), "new_tree": str(new), "old_version": tree_version(old),
              "new_version": tree_version(new),
              "scene": (f"benchmarks/step_time.py per_time_unit (N = 100 lattice, h = 1, shear 0.1487, "
                        f"{args.shear_time:g} time units, the tree's default scheme)") if args.random_rate is None
              else (f"benchmarks/step_time.py random_packing (examples/random.toml, seed 1, relaxed, then shear "
                    f"{args.random_rate:g} for {args.shear_time:g} time units, the tree's default scheme)"),
              "command": " ".join(["python", "benchmarks/redesign_step_time.py"] + sys.argv[1:]),
              "protocol": __doc__, "loadavg_end": Path("/proc/loadavg").read_text().split()[:3],
              "old_ms": summary(ms["old"]), "new_ms": summary(ms["new"]), "pair_ratios": summary(pairs),
              "runs": runs}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / args.output).write_text(json.dumps(result, indent=1) + "\n")
    print(f"default scheme: old {result['old_ms']['median']:.3f}, new {result['new_ms']['median']:.3f} CPU ms per "
          f"time unit; new/old pair ratio {result['pair_ratios']['median']:.3f} "
          f"[{result['pair_ratios']['q25']:.3f}, {result['pair_ratios']['q75']:.3f}]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--old", type=Path, help="the other femphase tree (its benchmarks/step_time.py is run)")
    parser.add_argument("--runs", type=int, default=4, help="blocks old, new, new, old of whole runs")
    parser.add_argument("--sessions", type=int, default=3, help="pairs of batch-interleaved workers")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--full-steps", type=int, default=10)
    parser.add_argument("--batch", type=int, default=20)
    parser.add_argument("--full-batch", type=int, default=2)
    parser.add_argument("--default-scheme", action="store_true",
                        help="time the default scheme per time unit of shear instead (whole runs only)")
    parser.add_argument("--shear-time", type=float, default=500.0,
                        help="time units of shear per run with --default-scheme")
    parser.add_argument("--random-rate", type=float,
                        help="with --default-scheme: the random packing sheared at this rate instead of the lattice")
    parser.add_argument("--steps-per-call", type=int,
                        help="with --default-scheme, on the lattice: steps per stepper call in a tree that takes "
                             "several (session 12 on; default its step_time.EXAMPLE_CALL)")
    parser.add_argument("--output", default="default_scheme_step_time.json",
                        help="with --default-scheme: the file in benchmarks/results/ to write")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    parser.add_argument("--gated", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        if args.default_scheme:
            default_worker(args.worker, args.shear_time, args.random_rate, args.steps_per_call)
        else:
            worker(args.worker, {"windows": args.steps, "full_mesh": args.full_steps},
                   {"windows": args.batch, "full_mesh": args.full_batch}, args.gated)
        return
    old, new = args.old.resolve(), NEW_TREE
    if args.default_scheme:
        default_scheme_runs(old, new, args)
        return
    runs = []
    for block in range(args.runs):
        for name in ("old", "new", "new", "old"):
            row = whole_run(old if name == "old" else new, args)
            row["which"] = name
            runs.append(row)
            print(f"run {name}: windows {row['windows']['median_ms']:.2f} ms/step (CPU {row['windows']['cpu_median_ms']:.2f}), "
                  f"full mesh {row['full_mesh']['median_ms']:.1f} (CPU {row['full_mesh']['cpu_median_ms']:.1f})", flush=True)
    sessions = []
    for s in range(args.sessions):
        sessions.append(batch_session(old, new, args))
        print(f"session {s}: windows batch ratios new/old (CPU) {np.round(_batch_ratios(sessions[-1], 'windows', args.batch), 3)}",
              flush=True)

    result = {"old_tree": str(old), "new_tree": str(new), "old_version": tree_version(old),
              "new_version": tree_version(new), "scene": "benchmarks/step_time.py (N = 100, h = 1, dt = 1, "
              "shear 0.1487; 300 windowed steps, 10 full-mesh steps)", "protocol": __doc__,
              "loadavg_end": Path("/proc/loadavg").read_text().split()[:3]}
    for mode in MODES:
        entry = {}
        for clock, key in (("wall", "median_ms"), ("cpu", "cpu_median_ms")):
            old_runs = [r[mode][key] for r in runs if r["which"] == "old"]
            new_runs = [r[mode][key] for r in runs if r["which"] == "new"]
            pairs = pair_ratios([r[mode][key] for r in runs])
            entry[f"runs_{clock}"] = {"old_ms": summary(old_runs), "new_ms": summary(new_runs),
                                     "ratio_of_medians": float(np.median(new_runs) / np.median(old_runs)),
                                     "pair_ratios": summary(pairs)}
        size = args.batch if mode == "windows" else args.full_batch
        for clock in ("wall", "cpu"):
            ratios = [r for s in sessions for r in _batch_ratios(s, mode, size, clock)]
            old_steps = [v for s in sessions for v in s["old"][mode][f"{clock}_ms"]]
            new_steps = [v for s in sessions for v in s["new"][mode][f"{clock}_ms"]]
            entry[f"batches_{clock}"] = {
                "old_ms": summary(old_steps), "new_ms": summary(new_steps),
                "ratio_of_medians": float(np.median(new_steps) / np.median(old_steps)),
                "batch_ratios": summary(ratios),
                "session_ratios": [float(np.median(_batch_ratios(s, mode, size, clock))) for s in sessions]}
        result[mode] = entry
    result["runs"] = [{k: r[k] for k in ("which", "femphase")}
                      | {m: {k: v for k, v in r[m].items() if not k.endswith("_ms") or "median" in k or "mean" in k}
                         for m in MODES} for r in runs]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "redesign_step_time.json").write_text(json.dumps(result, indent=1) + "\n")
    for mode in MODES:
        e = result[mode]
        print(f"{mode}: runs (wall) old {e['runs_wall']['old_ms']['median']:.2f} new {e['runs_wall']['new_ms']['median']:.2f} "
              f"ms/step, pair ratio {e['runs_wall']['pair_ratios']['median']:.3f} "
              f"[{e['runs_wall']['pair_ratios']['q25']:.3f}, {e['runs_wall']['pair_ratios']['q75']:.3f}]; "
              f"batches (CPU) old {e['batches_cpu']['old_ms']['median']:.2f} new {e['batches_cpu']['new_ms']['median']:.2f}, "
              f"ratio {e['batches_cpu']['batch_ratios']['median']:.3f} "
              f"[{e['batches_cpu']['batch_ratios']['q25']:.3f}, {e['batches_cpu']['batch_ratios']['q75']:.3f}]")


if __name__ == "__main__":
    main()
