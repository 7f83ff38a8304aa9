"""Milliseconds per time step: windows against the full mesh, in one run.

    python benchmarks/step_time.py [--steps N] [--full-steps M]

The paper's N = 100 hexagonal lattice under shear (γ̇ = 0.1487) at h = 1 with the default
dt = 1, first relaxed for 100 steps so the windows have their working size. Both modes run
in the same process, so the ratio is meaningful on a shared, noisy machine; the absolute
milliseconds are not. The last line is ``windows speedup over full mesh: <ratio>``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.simulation import Simulation
from femphase.stepping import Stepper


def time_steps(windows: bool, steps: int) -> dict:
    scene = common.lattice_scene(windows=windows)
    simulation = Simulation(scene)
    state = scene.initial_state()
    phase = scene.phases[0]
    relax = Stepper(simulation.domain, scene.model, scene.numerics, phase.dt, None, state.radii)
    for _ in range(20 if not windows else 100):
        relax.step(state)
    stepper = simulation.stepper(phase, state.radii)
    stepper.step(state)  # builds the factorisations: set-up cost, not per-step cost
    samples = []
    for _ in range(steps):
        start = time.perf_counter()
        stepper.step(state)
        samples.append(time.perf_counter() - start)
    samples = np.array(samples) * 1e3
    return {"mode": "windows" if windows else "full mesh", "steps": steps,
            "median_ms": float(np.median(samples)), "mean_ms": float(samples.mean()),
            "dofs_per_particle": float(np.mean([f.size for f in state.fields]))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--full-steps", type=int, default=10)
    args = parser.parse_args()
    windows = time_steps(True, args.steps)
    full = time_steps(False, args.full_steps)
    speedup = full["median_ms"] / windows["median_ms"]
    protocol_minutes = windows["median_ms"] * 1.02e5 / 1e3 / 60
    print(f"{'mode':<10} {'steps':>6} {'median ms/step':>15} {'mean ms/step':>13} {'dofs/particle':>14}")
    for row in (windows, full):
        print(f"{row['mode']:<10} {row['steps']:>6} {row['median_ms']:>15.2f} {row['mean_ms']:>13.2f} {row['dofs_per_particle']:>14.0f}")
    print(f"paper protocol (1.02e5 time units at dt = 1) with windows: {protocol_minutes:.1f} min")
    out = Path(__file__).parent / "results" / "step_time.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps({"windows": windows, "full_mesh": full, "speedup": speedup,
                               "protocol_minutes": protocol_minutes}, indent=2) + "\n")
    print(f"windows speedup over full mesh: {speedup:.1f}")


if __name__ == "__main__":
    main()
