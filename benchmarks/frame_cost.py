"""Cost of a step and of a frame, and peak memory, against N up to 1600 (issue 12).

    python benchmarks/frame_cost.py [--sizes 100 400 1600] [--steps 20]

Hexagonal lattices at the paper's density in channels grown in both directions: N = 100 in
70 × 240 (the paper's), 400 in 140 × 480, 1600 in 280 × 960, h = 1. Each N runs in its own
subprocess (so peak memory is its own): 100 relaxation steps at dt = 1 (windows reach their
working size), then ``--steps`` shear steps at the paper's velocity gradient (timed: median
CPU ms per step = per time unit at dt = 1), then frames (timed: every observable — shape,
energy, order — and the field data written to fields.xdmf, `femphase.io.point_data`). Peak
memory is the process's maximum resident set size. Exponents are least-squares slopes of
log(cost) against log N. Frames compute energies and field data window by window, so both
should grow linearly in N (before the one-core redesign they built dense N × nodes arrays:
about 10 GB at N = 1600).

Writes ``benchmarks/results/frame_cost.json``.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).parent / "results"
SIZES = (100, 400, 1600)
GRADIENT = 0.1487 / 240.0


def measure(n: int, steps: int) -> dict:
    import common  # noqa: F401  (pins BLAS threads before numpy loads)

    from femphase.io import point_data
    from femphase.scene import scene_from_dict
    from femphase.simulation import Frame, Simulation
    from femphase.stepping import Stepper

    scale = int(round(np.sqrt(n / 100)))
    scene = scene_from_dict({
        "domain": {"Lx": 70.0 * scale, "Ly": 240.0 * scale},
        "particles": {"layout": "hexagonal", "N": n, "per_row": 5 * scale},
        "output": {"fields": True, "observables": ["order"]},
        "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                    "flow": {"type": "shear", "rate": GRADIENT, "scale": "shear_rate"}}],
    })
    simulation = Simulation(scene)
    state = scene.initial_state()
    relax = Stepper(simulation.domain, scene.model, scene.numerics, 1.0, None, state.radii)
    for _ in range(100):
        relax.step(state)
    stepper = simulation.stepper(scene.phases[0], state.radii)
    stepper.step(state)  # builds the solvers
    step_times = []
    for _ in range(steps):
        start = time.process_time()
        stepper.step(state)
        step_times.append(time.process_time() - start)
    frame_times = []
    for _ in range(3):
        start = time.process_time()
        frame = Frame(state, scene.phases[0])
        for name in ("shape", "energy", "order"):
            observable = simulation.observable(name)
            values = observable(state, frame.particle)
            frame.particle.update({c: values[c] for c in observable.particle_columns})
        point_data(state, per_particle=False)
        frame_times.append(time.process_time() - start)
    return {"N": n, "nodes": simulation.domain.n_dofs, "step_ms": 1e3 * float(np.median(step_times)),
            "frame_ms": 1e3 * float(np.median(frame_times)),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def exponent(n: list[float], cost: list[float]) -> float:
    return float(np.polyfit(np.log(n), np.log(cost), 1)[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # the subprocess's size
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure(args.one, args.steps)))
        return
    rows = []
    for n in args.sizes:
        output = subprocess.run([sys.executable, __file__, "--one", str(n), "--steps", str(args.steps)],
                                check=True, capture_output=True, text=True).stdout
        rows.append(json.loads(output.strip().splitlines()[-1]))
        print(rows[-1], flush=True)
    sizes = [r["N"] for r in rows]
    result = {"rows": rows, "step_exponent": exponent(sizes, [r["step_ms"] for r in rows]),
              "frame_exponent": exponent(sizes, [r["frame_ms"] for r in rows]),
              "command": "python benchmarks/frame_cost.py " + " ".join(sys.argv[1:])}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "frame_cost.json").write_text(json.dumps(result, indent=2) + "\n")
    print(f"cost ∝ N^{result['step_exponent']:.2f} per step, N^{result['frame_exponent']:.2f} per frame; "
          f"peak memory at N = {sizes[-1]}: {rows[-1]['peak_rss_mb']:.0f} MB")


if __name__ == "__main__":
    main()
