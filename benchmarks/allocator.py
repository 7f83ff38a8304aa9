"""glibc's allocator with fixed mmap and trim thresholds against its defaults, same run, at
N = 100, 400 and 1600 (session 11: tried, not kept).

    python benchmarks/allocator.py [--runs 2] [--sizes 100 400 1600]

A step makes dozens of temporaries of 0.8 MB (N = 100) to 13 MB (N = 1600). glibc serves
blocks above its mmap threshold (128 kB at start, raised as such blocks are freed) with
fresh pages and returns the heap's free top above its trim threshold: in a loop of numpy
operations on 10⁵ positions that made every temporary page-fault in again (14 ns a position
against 3.1 with the thresholds fixed at 1 GiB / 2 GiB). Does the stepper see that? For
each size, ``scaling.py``'s measurement of one size (``scaling.py --one N``: the square
channel at the paper's density relaxed 100 time units, first order at dt = 1 per step, the
default scheme per time unit of shear, a frame, peak memory) runs in fresh subprocesses in
blocks default, tuned, tuned, default (``--runs`` blocks), the tuned ones with
``mallopt(M_MMAP_THRESHOLD, 64 MiB)`` and ``mallopt(M_TRIM_THRESHOLD, 1 GiB)`` before
anything is imported. Prints, per size and setting, the medians, the tuned/default ratio of
each adjacent pair (page faults: minor faults per time unit of the default scheme's shear),
and the cost exponents over N of each setting; writes
``results/allocator.json``. Numbers: benchmarks/README.md ("Session 11").
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads, for the subprocesses too)
import numpy as np

from scaling import SIZES, fitted_exponent

RESULTS = Path(__file__).parent / "results"
SCALING = Path(__file__).parent / "scaling.py"
TIMES = ("euler_ms_per_step", "default_ms_per_time_unit", "frame_ms")
COSTS = TIMES + ("default_page_faults_per_time_unit",)
SETTINGS = ("glibc default", "tuned")


#: Run before scaling.py in the tuned subprocesses (glibc's M_MMAP_THRESHOLD = -3, M_TRIM_THRESHOLD = -1)
TUNE = ("import ctypes, runpy, sys; libc = ctypes.CDLL('libc.so.6'); "
        "libc.mallopt(-3, 64 * 2**20); libc.mallopt(-1, 2**30); "
        "sys.argv = sys.argv[1:]; sys.path.insert(0, {folder!r}); runpy.run_path(sys.argv[0], run_name='__main__')")


def measure(n: int, setting: str) -> dict:
    command = [str(SCALING), "--one", str(n)]
    if setting == "tuned":
        command = ["-c", TUNE.format(folder=str(SCALING.parent))] + command
    output = subprocess.run([sys.executable] + command, check=True, capture_output=True, text=True).stdout
    return json.loads(output.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=2, help="blocks default, tuned, tuned, default per size")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    args = parser.parse_args()
    rows = {}
    for n in args.sizes:
        runs = {setting: [] for setting in SETTINGS}
        for _ in range(args.runs):
            for setting in SETTINGS + SETTINGS[::-1]:
                runs[setting].append(measure(n, setting))
                print(n, setting, {k: round(runs[setting][-1][k], 2) for k in COSTS + ("peak_rss_mb",)}, flush=True)
        # pairs: the k-th tuned run with the k-th default run (adjacent in the block pattern)
        ratios = {key: [t[key] / d[key] if d[key] else float("nan") for t, d in zip(runs["tuned"], runs["glibc default"])]
                  for key in COSTS + ("peak_rss_mb",)}
        rows[n] = {"runs": runs, "median": {s: {key: float(np.median([r[key] for r in runs[s]]))
                                                for key in COSTS + ("peak_rss_mb",)} for s in SETTINGS},
                   "ratios": {key: [float(x) for x in v] for key, v in ratios.items()}}
    print("| N | cost | glibc default | tuned | tuned / default (pairs) |\n|---|---|---|---|---|")
    for n, row in rows.items():
        for key in COSTS + ("peak_rss_mb",):
            pairs = ", ".join(f"{x:.2f}" for x in row["ratios"][key])
            print(f"| {n} | {key} | {row['median']['glibc default'][key]:.3g} | {row['median']['tuned'][key]:.3g} | "
                  f"{pairs} |")
    sizes = np.array(list(rows), float)
    exponents = {}
    if len(sizes) > 1:
        for setting in SETTINGS:
            exponents[setting] = {key: fitted_exponent(sizes, np.array([rows[n]["median"][setting][key] for n in rows]))
                                  for key in TIMES}
            print(f"{setting}: " + ", ".join(f"{key} ∝ N^{e:.2f}" for key, e in exponents[setting].items()))
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "allocator.json").write_text(json.dumps(
        {"by_N": {str(n): row for n, row in rows.items()}, "exponents": exponents,
         "command": "python benchmarks/allocator.py " + " ".join(sys.argv[1:])}, indent=2) + "\n")


if __name__ == "__main__":
    main()
