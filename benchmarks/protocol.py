"""The paper's whole protocol, run end to end as a user runs it: CPU minutes per run.

    python benchmarks/protocol.py [--rates R ...] [--duration T] [--old TREE] [--scene FILE]
                                  [--set KEY=VALUE ...] [--output NAME]

Each run is ``femphase run examples/random.toml`` in a child process (BLAS threads pinned):
N = 100 discs of R/2 at random centroids (seed 1), relaxed 2000 time units without flow,
then sheared for ``--duration`` (default the paper's 10⁵) at rate R, with the example's
frames and checkpoints every 400 time units and T1 looks every 20. Its CPU time (user +
system, from the child's rusage) is the measurement: relaxation, shear, frames, output and
start-up, where ``step_time.py`` extrapolates the first 500 time units of shear (the
windows' growth as the particles first elongate costs more there than later: at γ̇ = 1,
120 new window layouts in the first 1000 time units, ~10 per 1000 after t = 6000).

With ``--old TREE`` each rate runs on both trees at once, one process per core, so that
both see the same machine load, and the new/old CPU ratio is reported; without it the runs
go one at a time. Each tree runs its own copy of the scene (``--scene``, a file of its
``examples/``, default random.toml): the run its user would make, with that tree's
defaults (``--scene hexagonal.toml --rates 0.1487 --duration 20000`` is the lattice
example as it stands). ``--rates none`` keeps the scene's own flow (one run, e.g. a Stokes
flow); ``--set`` passes scene overrides to every run (``--set phases.0.duration=100``).
Results: ``results/protocol.json`` (``--output`` renames it).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import common  # pins BLAS threads, for the children too (they inherit the environment)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).parent / "results"


def start(tree: Path, scene: str, rate: float | None, duration: float, directory: Path,
          sets: list[str]) -> subprocess.Popen:
    """A child running ``tree``'s examples/``scene`` with its second phase's flow at ``rate``
    (None: the scene's own) for ``duration``, and the overrides ``sets``, with ``tree``'s
    femphase into ``directory``."""
    overrides = ([] if rate is None else [f"phases.1.flow.rate={rate}"]) + [f"phases.1.duration={duration}", *sets]
    command = [sys.executable, "-m", "femphase.cli", "run", str(tree / "examples" / scene),
               "-o", str(directory), "-q"] + [item for key in overrides for item in ("--set", key)]
    environment = {**os.environ, "PYTHONPATH": str(tree)}
    return subprocess.Popen(command, env=environment, cwd=tree, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def finish(child: subprocess.Popen, started: float) -> dict:
    """Wait for ``child``: its CPU seconds, wall seconds and peak resident memory (MiB: ru_maxrss / 1024)."""
    _, status, usage = os.wait4(child.pid, 0)
    child.returncode = os.waitstatus_to_exitcode(status)
    errors = child.stderr.read().decode()
    if child.returncode != 0:
        raise RuntimeError(f"protocol run failed (exit {child.returncode}): {errors}")
    return {"cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": time.perf_counter() - started,
            "peak_mb": usage.ru_maxrss / 1024}


def second_phase_duration(duration: float, sets: list[str]) -> float:
    """The second phase's duration the runs use: ``--duration``, unless a ``--set`` of
    ``phases.1.duration`` (applied after it) overrides it."""
    for assignment in reversed(sets):
        key, _, value = assignment.partition("=")
        if key.strip() == "phases.1.duration":
            return float(value)
    return duration


def run_rate(trees: dict[str, Path], scene: str, rate: float | None, duration: float, scratch: Path,
             sets: list[str]) -> dict[str, dict]:
    """The protocol at ``rate`` on every tree at once (one child per tree)."""
    started = time.perf_counter()
    children = {name: start(tree, scene, rate, duration, scratch / f"{name}-{rate}", sets)
                for name, tree in trees.items()}
    return {name: finish(child, started) for name, child in children.items()}


def _rate(text: str) -> float | None:
    return None if text == "none" else float(text)


def _commit(tree: Path) -> str | None:
    """The git commit checked out in ``tree`` (None outside git), with "+changes" where its
    femphase/ differs from that commit: the run measured code no commit holds."""
    found = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if found.returncode != 0 or not found.stdout.strip():
        return None
    changed = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--", "femphase"],
                             capture_output=True, text=True).stdout.strip()
    return found.stdout.strip() + ("+changes" if changed else "")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rates", type=_rate, nargs="+", default=[0.0161, 0.1083, 1.0],
                        help="shear rates of the second phase, or none: the scene's own flow")
    parser.add_argument("--duration", type=float, default=1e5, help="time units of shear (the paper: 10⁵)")
    parser.add_argument("--old", type=Path, help="another femphase tree, run beside this one")
    parser.add_argument("--scene", default="random.toml", help="a scene file of each tree's examples/")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="a scene override for every run")
    parser.add_argument("--output", default="protocol.json")
    args = parser.parse_args()
    trees = {"new": ROOT} if args.old is None else {"new": ROOT, "old": args.old.resolve()}
    load = common.load_average()
    # the code each child imports at its start: read now, as a tree's HEAD may move during the runs
    commits = {name: _commit(tree) for name, tree in trees.items()}
    shear_time = second_phase_duration(args.duration, args.set)
    rows = {}
    with tempfile.TemporaryDirectory(prefix="femphase-protocol-") as scratch:
        for rate in args.rates:
            rows[str(rate)] = run_rate(trees, args.scene, rate, args.duration, Path(scratch), args.set)
            line = "; ".join(f"{name} {r['cpu_s'] / 60:.2f} CPU-min ({r['peak_mb']:.0f} MiB)"
                             for name, r in rows[str(rate)].items())
            if args.old is not None:
                line += f"; new/old {rows[str(rate)]['new']['cpu_s'] / rows[str(rate)]['old']['cpu_s']:.3f}"
            flow = "its own flow" if rate is None else f"γ̇ = {rate}"
            print(f"{args.scene}, {flow}, second phase {shear_time:g} time units: {line}", flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / args.output).write_text(json.dumps({
        "scene": f"examples/{args.scene}", "shear_time": shear_time, "sets": args.set, "runs": rows,
        "trees": {name: {"path": str(tree), "commit": commits[name]} for name, tree in trees.items()},
        "load_average": {"start": load, "end": common.load_average()},
        "command": "python benchmarks/protocol.py " + " ".join(sys.argv[1:])}, indent=2) + "\n")


if __name__ == "__main__":
    main()
