"""Each window its own CG against one CG on the whole block-diagonal vector, in one process.

examples/straight_mesh.toml (N = 100, seed 1, dt = 10, default scheme) is relaxed once; two
copies of the relaxed suspension then run in Stokes flow of centre-line velocity
``--velocity``, in alternating chunks of ``--chunk`` time units, one with the meshes' CG
(:func:`femphase.fem.blocks.conjugate_gradient`: every window its own Krylov space and its
own stop, in one compiled pass) and one with the whole-vector CG written here as the
reference (one Krylov space for all windows: a scipy product and compiled vector updates
per iteration, every window iterating until the slowest is in). Both stop at the same
goal, max|D⁻¹r| over the whole vector. Alternating chunks in one process see the shared
machine's slow spells alike; the ratio is per chunk, the first chunk of each dropped
(compilation). Also the CPU inside the solves, and the iterations as products with the
whole vector.

    python benchmarks/window_cg.py --chunk 100 --chunks 10
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from pathlib import Path

import common  # pins BLAS threads
import numba
import numpy as np

import femphase.timestepping.stepper as stepper_module
from femphase.fem.blocks import RESIDUAL_REDUCTION
from femphase.run.simulation import Simulation
from femphase.scene import load_scene

RESULT = Path(__file__).parent / "results" / "window_cg.json"


@numba.njit(nogil=True, boundscheck=False)
def _update(x, r, p, q, inverse, alpha):
    """x += α p, r −= α q in one pass; (max|D⁻¹r|, rᵀD⁻¹r) of the new r."""
    a = x.dtype.type(alpha)
    largest = x.dtype.type(0.0)
    rz = 0.0
    for i in range(x.size):
        x[i] += a * p[i]
        residual = r[i] - a * q[i]
        r[i] = residual
        z = inverse[i] * residual
        rz += np.float64(residual * z)
        largest = max(largest, abs(z))
    return float(largest), rz


@numba.njit(nogil=True, boundscheck=False)
def _direction(p, r, inverse, beta):
    """p ← D⁻¹r + β p."""
    b = p.dtype.type(beta)
    for i in range(p.size):
        p[i] = inverse[i] * r[i] + b * p[i]


def whole_vector_cg(matrix, offsets, inverse_diagonal, rhs, guess, tolerance, maxiter=1000, guess_product=None):
    """Jacobi-preconditioned CG on the whole block-diagonal system, to the goal of
    :func:`~femphase.fem.blocks.conjugate_gradient`, with its signature; every window is
    counted with the whole vector's iterations."""
    x = np.array(guess, dtype=np.result_type(rhs, guess), copy=True)
    inverse = np.asarray(inverse_diagonal).astype(x.dtype, copy=False)
    scale = float(np.max(np.abs(inverse * rhs), initial=0.0))
    goal = tolerance * scale if scale > 0.0 else np.inf
    r = (rhs - (matrix @ x if guess_product is None else guess_product)).astype(x.dtype, copy=False)
    z = inverse * r
    largest = float(np.max(np.abs(z), initial=0.0))
    goal = min(goal, RESIDUAL_REDUCTION * largest)
    iterations = 0
    p, rz = z, float(np.dot(r, z))
    while largest > goal:
        if iterations == maxiter:
            raise RuntimeError(f"the whole-vector CG did not converge in {maxiter} iterations")
        iterations += 1
        q = matrix @ p
        largest, next_rz = _update(x, r, p, q, inverse, rz / float(np.dot(p, q)))
        if largest > goal:
            _direction(p, r, inverse, next_rz / rz)
            rz = next_rz
    return x, np.full(len(offsets) - 1, iterations), r


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relax", type=float, default=400.0, help="time units of relaxation (default 400)")
    parser.add_argument("--chunk", type=float, default=100.0, help="time units of flow per chunk (default 100)")
    parser.add_argument("--chunks", type=int, default=10, help="chunks of each kind (default 10)")
    parser.add_argument("--velocity", type=float, default=0.1, help="centre-line velocity U (default 0.1)")
    parser.add_argument("--output", type=Path, default=RESULT)
    args = parser.parse_args()

    flow = f'{{type = "stokes", max_velocity = {args.velocity}}}'
    scene = load_scene(common.STRAIGHT_MESH_SCENE, ["phases.0.dt=10.0", "phases.1.dt=10.0", "output.fields=false",
                                                     f"phases.0.duration={args.relax}",
                                                     f"phases.1.duration={args.chunk}", f"phases.1.flow={flow}"])
    relaxed = scene.initial_state()
    stepper = Simulation(scene).stepper(scene.phases[0], relaxed.radii)
    stepper.scheme.start_phase(relaxed)
    stepper.step(relaxed, scene.phases[0].n_steps)

    solvers = {"per_window": stepper_module.conjugate_gradient, "whole_vector": whole_vector_cg}
    solve_cpu = dict.fromkeys(solvers, 0.0)

    def timed(kind):
        def solve(*args, **kwargs):
            started = time.process_time()
            out = solvers[kind](*args, **kwargs)
            solve_cpu[kind] += time.process_time() - started
            return out
        return solve

    states, steppers = {}, {}
    for kind in solvers:  # each its own domain, so that neither thrashes the other's caches
        states[kind] = copy.deepcopy(relaxed)
        steppers[kind] = Simulation(scene).stepper(scene.phases[1], relaxed.radii)
        steppers[kind].scheme.start_phase(states[kind])
    cpu = {kind: [] for kind in solvers}
    try:
        for chunk in range(args.chunks):
            if chunk == 1:
                solve_cpu.update(dict.fromkeys(solvers, 0.0))
            for kind in (list(solvers) if chunk % 2 == 0 else list(solvers)[::-1]):
                stepper_module.conjugate_gradient = timed(kind)
                started = time.process_time()
                steppers[kind].step(states[kind], scene.phases[1].n_steps)
                cpu[kind].append(time.process_time() - started)
    finally:
        stepper_module.conjugate_gradient = solvers["per_window"]
    ratios = [ours / theirs for ours, theirs in zip(cpu["per_window"][1:], cpu["whole_vector"][1:])]
    result = {
        "machine": common.machine(), "relax": args.relax, "chunk": args.chunk, "chunks": args.chunks,
        "velocity": args.velocity,
        "flow_cpu_s": {kind: sum(values[1:]) for kind, values in cpu.items()},
        "chunk_ratios": ratios,
        "flow_cpu_ratio": sum(cpu["per_window"][1:]) / sum(cpu["whole_vector"][1:]),
        "solve_cpu_s": solve_cpu, "solve_cpu_ratio": solve_cpu["per_window"] / solve_cpu["whole_vector"],
        "whole_vector_products": {kind: step.krylov_iterations for kind, step in steppers.items()},
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    print(f"per-window/whole-vector CG: flow CPU {result['flow_cpu_ratio']:.3f} (chunks "
          f"{', '.join(f'{r:.2f}' for r in ratios)}), CPU in the solves {result['solve_cpu_ratio']:.3f}, "
          f"products {result['whole_vector_products']['per_window']:.0f} against "
          f"{result['whole_vector_products']['whole_vector']:.0f}")


if __name__ == "__main__":
    main()
