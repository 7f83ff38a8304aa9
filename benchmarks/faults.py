"""Fault counts: kills and resumes of a real run, and bad inputs.

    python benchmarks/faults.py [--kills 40] [--seed 0]

1. Kills a real ``femphase run`` (the small scene of :mod:`femphase.testing.faults`) ``--kills`` times —
   SIGKILL at random moments and at every failpoint (half-written CSV rows, field frames,
   checkpoints, fields.xdmf, run.json before their rename), SIGTERM and SIGINT — resuming
   after each, and compares the outputs with an uninterrupted run.
2. Feeds every generated bad input (:func:`femphase.testing.fuzzing.bad_inputs`: bad scenes,
   ``--set`` values, mesh files, run directories) to the command line, and again into a
   finished run directory with ``--resume``.

Writes ``benchmarks/results/faults.json`` with the counts: kill points tried, runs whose
resumed outputs are bit-identical to the uninterrupted one, bad inputs tried, rejected with a
clean message (exit 2, the key named, the output untouched), tracebacks (must be 0).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)

from femphase.testing.faults import SCENE, campaign
from femphase.testing.fuzzing import run_fuzz


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="femphase-faults-") as folder:
        start = time.perf_counter()
        kills = campaign(SCENE, Path(folder) / "kills", args.kills, seed=args.seed)
        kill_seconds = time.perf_counter() - start
        fuzz = run_fuzz(seed=args.seed, workdir=Path(folder) / "fuzz")
    by_kind: dict[str, int] = {}
    for event in kills["events"]:
        kind = event["kind"].split(":")[0]
        by_kind[kind] = by_kind.get(kind, 0) + 1
    result = {
        "kill_points_tried": kills["kill_points"],
        "kill_points_by_kind": by_kind,
        "kill_exit_codes": sorted({e["exit_code"] for e in kills["events"]}),
        "killed_runs": kills["runs"],
        "resumes_bit_identical": kills["resumes_bit_identical"],
        "differences": kills["differences"],
        "kill_seconds": round(kill_seconds, 1),
        "bad_inputs_distinct": fuzz["inputs"],
        "bad_inputs_tried": fuzz["tried"],
        "rejected_with_a_clean_message": fuzz["rejected_cleanly"],
        "tracebacks": fuzz["tracebacks"],
        "bad_input_failures": fuzz["failures"],
        "fuzz_seconds": round(fuzz["seconds"], 1),
        "command": "python benchmarks/faults.py " + f"--kills {args.kills} --seed {args.seed}",
    }
    out = Path(__file__).parent / "results" / "faults.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"kill points tried: {result['kill_points_tried']} {by_kind}")
    print(f"runs resumed bit-identical: {result['resumes_bit_identical']} of {result['killed_runs']}")
    print(f"bad inputs tried: {result['bad_inputs_tried']} ({result['bad_inputs_distinct']} distinct); rejected "
          f"with a clean message: {result['rejected_with_a_clean_message']}; tracebacks: {result['tracebacks']}")


if __name__ == "__main__":
    main()
