"""How the T1 rate counted from frames depends on the frame interval, on one run.

    python -m verification.t1_sampling verification/runs/poiseuille_reduced/runs/rate=1.0_seed=1

T1 events are Delaunay edge flips between consecutive frames
(:func:`femphase.analysis.lattice.t1_event_times`); where neighbours change more than once
between two frames the flips no longer match and are missed. This counts them over the
run's last phase from every k-th frame (k = 1, 2, 5, 10) of the same trajectory and prints
T1 events per particle per 1000 time units against the frame spacing.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from femphase.aggregate import last_phase_frames
from femphase.io.reader import open_run
from femphase.analysis.lattice import t1_event_times

STRIDES = (1, 2, 5, 10)


def t1_rates(directory: Path, strides: tuple[int, ...] = STRIDES) -> list[tuple[float, float]]:
    """(frame spacing, T1 events per particle per 1000 time units) for each stride, over the
    last phase (from its last frame before the phase starts)."""
    run = open_run(directory).complete()
    phases = json.loads((directory / "run.json").read_text())["settings"]["phases"]
    start = max(int(last_phase_frames(run.time, phases)[0]) - 1, 0)
    out = []
    for stride in strides:
        frames = np.arange(start, run.time.size, stride)
        centroids = np.stack([run.x[frames], run.y[frames]], axis=-1)
        events = t1_event_times(list(centroids), run.time[frames], run.length).size
        span = float(run.time[frames[-1]] - run.time[frames[0]])
        out.append((float(run.time[frames[1]] - run.time[frames[0]]), 1000.0 * events / (run.n_particles * span)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a run directory (particles.csv, run.json)")
    args = parser.parse_args()
    print("| frame spacing | T1 per particle per 1000 t |\n|---|---|")
    for spacing, rate in t1_rates(args.run):
        print(f"| {spacing:g} | {rate:.2f} |")


if __name__ == "__main__":
    main()
