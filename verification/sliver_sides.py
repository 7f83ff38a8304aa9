"""What leaving sliver sides out of the order parameters' neighbours changes in Ψ6 and Ψ2^L.

    python -m verification.sliver_sides

The order parameters take the periodic Delaunay pairs of the centroids without the longest
side of every sliver triangle (``periodic_delaunay_pairs(…, sliver_sides=False)``,
docs/outputs.md). The Fig. 1a tables of verification/README.md were written with those
sides included. This runs examples/random.toml (relaxed 1000 time units, then sheared
3000 at γ̇ = 0.1083, frames every 50) and recomputes Ψ6 and Ψ2^L of every frame with and
without the sliver sides. Writes results/sliver_sides.json.
"""

from __future__ import annotations

import os

# one BLAS thread: the machine's two cores are shared with other long runs
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import argparse  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from femphase.io.files import write_json  # noqa: E402
from verification.physics_common import REPO, RESULTS  # noqa: E402

RATE = 0.1083
SETTINGS = ["output.fields=false", "phases.0.duration=1000", "phases.0.frame_interval=500",
            "phases.1.duration=3000", "phases.1.frame_interval=50", f'phases.1.flow={{type="shear", rate={RATE}}}']


def measure(directory: Path) -> dict:
    """Run the scene into ``directory`` and compare the two neighbour sets frame by frame."""
    from femphase.analysis.lattice import bond_order, global_order, nematic_order, periodic_delaunay_pairs
    from femphase.io.reader import open_run
    from femphase.run.runner import run_scene
    from femphase.scene import load_scene

    run_scene(load_scene(REPO / "examples" / "random.toml", SETTINGS), directory, progress=False,
              status_interval=None)
    run = open_run(directory).complete()
    removed, psi6, psi2 = [], [], []
    for k in np.flatnonzero(run.time > run.shear_start):
        centroids = np.stack([run.x[k], run.y[k]], axis=1)
        every, order = (periodic_delaunay_pairs(centroids, run.length, sliver_sides=keep) for keep in (True, False))
        removed.append(len(every) - len(order))
        psi6.append([global_order(bond_order(centroids, run.length, pairs)) for pairs in (every, order)])
        psi2.append([global_order(nematic_order(run.orientation[k], pairs, run.n_particles)) for pairs in (every, order)])
    psi6, psi2 = np.array(psi6), np.array(psi2)
    change6, change2 = psi6[:, 1] - psi6[:, 0], psi2[:, 1] - psi2[:, 0]
    return {
        "scene": "examples/random.toml", "settings": SETTINGS, "frames": len(removed),
        "sides_removed_per_frame": {"mean": float(np.mean(removed)), "max": int(np.max(removed))},
        "Psi6_change": {"mean": float(change6.mean()), "largest": float(np.abs(change6).max())},
        "Psi2_change": {"mean": float(change2.mean()), "largest": float(np.abs(change2).max())},
        "Psi6_mean_with_sides": float(psi6[:, 0].mean()), "Psi2_mean_with_sides": float(psi2[:, 0].mean()),
        "command": "python -m verification.sliver_sides",
    }


def main() -> None:
    argparse.ArgumentParser(prog="python -m verification.sliver_sides",
                            description=__doc__.split("\n\n")[0]).parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        result = measure(Path(scratch) / "run")
    write_json(RESULTS / "sliver_sides.json", result)
    print(f"{result['frames']} frames, {result['sides_removed_per_frame']['mean']:.2f} sides removed per frame; "
          f"Psi6 {result['Psi6_change']['mean']:+.4f} (largest {result['Psi6_change']['largest']:.4f}), "
          f"Psi2 {result['Psi2_change']['mean']:+.4f} (largest {result['Psi2_change']['largest']:.4f})")


if __name__ == "__main__":
    main()
