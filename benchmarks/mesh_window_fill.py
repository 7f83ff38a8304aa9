"""How much of a mesh window's box does its particle need?

    python benchmarks/mesh_window_fill.py [--relax 400] [--flow 200]

A mesh flow step's cost is its sparse products and vector work, each proportional to the
windows' positions (docs/decisions/0039-mesh-products-at-kernel-floor.md). A window is the
mesh's dofs inside a box: the particle's φ > threshold set, a margin of 4 on every side
(the paper's rule), room for motion and slack for fewer refits. This script measures, at a
real layout, which fraction of those positions a window shaped to its particle would keep:

* **dilated**: the dofs within a distance m of the φ > 0.01 set (periodic in x), m = 2 … 5
  (m = 4: the paper's margin alone, m = 5: with one unit of room);
* **disc**: the dofs within the farthest φ > 0.01 dof's distance + m of the set's centroid.

Both counts are of the box's own dofs (a dilation or disc reaching past its box is cut
there; the boxes keep the margin, so this matters only for the discs).
examples/straight_mesh.toml (N = 100, seed 1) after ``--relax`` time units of relaxation and
``--flow`` of its Stokes flow, default scheme. Writes ``results/mesh_window_fill.json``.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np
from scipy.spatial import cKDTree

from femphase.run.simulation import Simulation
from femphase.scene import load_scene

RESULT = Path(__file__).parent / "results" / "mesh_window_fill.json"
SCENE = Path(__file__).parents[1] / "examples" / "straight_mesh.toml"
THRESHOLD = 0.01
DISTANCES = (2, 3, 4, 5)


def window_fill(state) -> dict:
    """Positions of the boxes, and the fractions the dilated and disc windows keep."""
    domain = state.domain
    xy, period = domain.coordinates, domain.period
    boxes = 0
    dilated = dict.fromkeys(DISTANCES, 0)
    disc = dict.fromkeys(DISTANCES, 0)
    for window, field in zip(state.windows, state.fields):
        points = xy[:, domain.window_dofs(window)].T.copy()
        # unwrapped about the field's peak: a box may straddle the periodic seam
        peak = points[np.argmax(field)]
        points[:, 0] = peak[0] + (points[:, 0] - peak[0] + period / 2) % period - period / 2
        inside = points[field > THRESHOLD]
        boxes += len(points)
        distance, _ = cKDTree(inside).query(points)
        centre = inside.mean(axis=0)
        reach = np.hypot(*(inside - centre).T).max()
        from_centre = np.hypot(*(points - centre).T)
        for m in DISTANCES:
            dilated[m] += int((distance <= m).sum())
            disc[m] += int((from_centre <= reach + m).sum())
    return {"box_positions": boxes, "dilated": {m: v / boxes for m, v in dilated.items()},
            "disc": {m: v / boxes for m, v in disc.items()}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--relax", type=float, default=400.0)
    parser.add_argument("--flow", type=float, default=200.0)
    args = parser.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = load_scene(SCENE, [f"phases.0.duration={args.relax:g}", f"phases.1.duration={args.flow:g}",
                                   f"phases.0.frame_interval={args.relax:g}", f"phases.1.frame_interval={args.flow:g}"])
    state = scene.initial_state()
    start = time.process_time()
    Simulation(scene).run(state, [])
    result = {"scene": str(SCENE.name), "relax": args.relax, "flow": args.flow, "threshold": THRESHOLD,
              "cpu_s": round(time.process_time() - start, 1), **window_fill(state)}
    RESULT.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
