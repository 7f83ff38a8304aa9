"""The same suspension on the structured channel and on the unstructured straight mesh.

examples/random.toml (N = 100 random discs, seed 1, 70 × 240) in Poiseuille flow u =
4U y(Ly − y)/Ly² against examples/straight_mesh.toml (the same channel, N and seed, as an
unstructured Delaunay mesh, in the Stokes flow of centre-line velocity U), both at the
default scheme and dt = 10, relaxed for ``--relax`` time units and then run for ``--flow``
time units of flow. Each run is its own process (peak memory is per process); the kinds
alternate, ``--repeats`` times, and the ratios are mesh/grid within the same run:

* CPU per time unit under flow (process CPU clock around the flow phase's steps);
* peak resident memory of the whole process;
* the mesh path with its previous solvers (``numerics.solver = "direct"``: an LU per box
  and a complex LU per window for the advection) as a third kind, with ``--direct``;
* the mesh with the Galerkin advection at every Courant number (no semi-Lagrangian steps,
  :mod:`femphase.domains.mesh.semi_lagrangian`) as a kind, with ``--galerkin``;
* the mesh on box windows (``numerics.mesh_windows = "boxes"``; the default on meshes with
  the batched solves is shaped windows, :mod:`femphase.domains.mesh.shapes`) as a kind,
  with ``--boxes``;
* the mesh with the Runge–Kutta advection (``numerics.mesh_advection = "runge-kutta"``; the
  default below Courant number 2 is the Taylor–Galerkin step,
  :mod:`femphase.domains.mesh.advection`) as a kind, with ``--runge-kutta``.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/mesh_parity.py --relax 400 --flow 1600 --repeats 4 --direct

Processes a minute apart see different spells of the shared machine: between them the
channel's flow alone moved by up to 1.5×, and the ratio with it. ``--interleaved N`` runs
the suspensions in one process instead (with ``--boxes`` and ``--runge-kutta`` those kinds
too), relaxed one after
the other, then their flows in N chunks of ``--flow`` time units each (the order rotated
every chunk), and reports each mesh kind's ratio to the grid per chunk and over all (the
first chunk dropped: compilation); no memory in this mode (one process holds all):

    python benchmarks/mesh_parity.py --relax 400 --flow 100 --interleaved 25 --boxes \\
        --output benchmarks/results/mesh_parity_shapes.json
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import common  # pins BLAS threads; run_phases

ROOT = Path(__file__).resolve().parents[1]
RESULT = Path(__file__).parent / "results" / "mesh_parity.json"
SCENES = {
    "grid": ("examples/random.toml", ["phases.1.name=\"flow\""], "poiseuille"),
    "mesh": ("examples/straight_mesh.toml", ["phases.0.dt=10.0", "phases.1.dt=10.0"], "stokes"),
    "mesh_direct": ("examples/straight_mesh.toml", ["phases.0.dt=10.0", "phases.1.dt=10.0",
                                                    "numerics.solver=\"direct\""], "stokes"),
    "mesh_galerkin": ("examples/straight_mesh.toml", ["phases.0.dt=10.0", "phases.1.dt=10.0"], "stokes"),
    "mesh_boxes": ("examples/straight_mesh.toml", ["phases.0.dt=10.0", "phases.1.dt=10.0",
                                                   "numerics.mesh_windows=\"boxes\""], "stokes"),
    "mesh_runge_kutta": ("examples/straight_mesh.toml", ["phases.0.dt=10.0", "phases.1.dt=10.0",
                                                         "numerics.mesh_advection=\"runge-kutta\""], "stokes"),
}
THREADS = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def scene_of(kind: str, relax: float, flow: float, velocity: float):
    """The scene of one kind: ``relax`` time units of relaxation, then ``flow`` of its flow at
    velocity scale ``velocity``."""
    from femphase.scene import load_scene

    path, sets, flow_type = SCENES[kind]
    velocity_key = "rate" if flow_type == "poiseuille" else "max_velocity"
    flow_table = f'{{type = "{flow_type}", {velocity_key} = {velocity}}}'
    return load_scene(ROOT / path, [*sets, f"phases.0.duration={relax}", f"phases.1.duration={flow}",
                                     f"phases.1.flow={flow_table}", "output.fields=false"])


def child(kind: str, relax: float, flow: float, velocity: float) -> dict:
    """Run one kind in this process; its CPU per time unit under flow and peak memory."""
    if kind == "mesh_galerkin":  # the Galerkin step at every Courant number
        from femphase.domains.mesh import semi_lagrangian

        semi_lagrangian.COURANT = float("inf")
    state, cpu, iterations, _ = common.run_phases(scene_of(kind, relax, flow, velocity))
    return {"kind": kind, "relax_cpu_s": cpu[0], "flow_cpu_s": cpu[1], "flow_ms_per_time_unit": 1e3 * cpu[1] / flow,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
            "window_cg_iterations": iterations[-1], "positions": int(sum(f.size for f in state.fields))}


def interleaved(relax: float, chunk: float, chunks: int, velocity: float, kinds: tuple[str, ...] = ("grid", "mesh")
                ) -> dict:
    """The channel ("grid") and the mesh kinds of ``kinds`` in this process: each relaxed
    ``relax`` time units, then their flows in ``chunks`` chunks of ``chunk`` time units, the
    kinds' order rotated every chunk; CPU per chunk on the process clock, and each mesh
    kind's over the grid's per chunk and over the chunks after the first."""
    scenes, states, steppers = {}, {}, {}
    for kind in kinds:
        scenes[kind] = scene_of(kind, relax, chunk, velocity)
        states[kind], steppers[kind] = common.relaxed_flow(scenes[kind])
    cpu = {kind: [] for kind in kinds}
    for index in range(chunks):
        turn = index % len(kinds)
        for kind in kinds[turn:] + kinds[:turn]:
            started = time.process_time()
            steppers[kind].step(states[kind], scenes[kind].phases[1].n_steps)
            cpu[kind].append(time.process_time() - started)
    meshes = {}
    for kind in kinds[1:]:
        meshes[kind] = {"chunk_ratios": [mesh / grid for mesh, grid in zip(cpu[kind][1:], cpu["grid"][1:])],
                        "flow_cpu_ratio": sum(cpu[kind][1:]) / sum(cpu["grid"][1:]),
                        "window_cg_iterations": round(float(steppers[kind].krylov_iterations), 1),
                        "positions": int(sum(f.size for f in states[kind].fields))}
    return {"mode": "interleaved", "relax": relax, "chunk": chunk, "chunks": chunks, "velocity": velocity,
            "flow_cpu_s": cpu, **meshes.get("mesh", {}), "meshes": meshes, "target": 3.0}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relax", type=float, default=400.0, help="time units of relaxation (default 400)")
    parser.add_argument("--flow", type=float, default=1600.0, help="time units of flow (default 1600)")
    parser.add_argument("--velocity", type=float, default=0.1, help="centre-line velocity U (default 0.1)")
    parser.add_argument("--repeats", type=int, default=1, help="alternations of the kinds (default 1)")
    parser.add_argument("--direct", action="store_true", help="also the mesh with per-box LU solvers")
    parser.add_argument("--galerkin", action="store_true",
                        help="also the mesh with the Galerkin advection at every Courant number (no semi-Lagrangian)")
    parser.add_argument("--boxes", action="store_true",
                        help="also the mesh with box windows (numerics.mesh_windows = \"boxes\")")
    parser.add_argument("--runge-kutta", action="store_true",
                        help="also the mesh with the Runge–Kutta advection (numerics.mesh_advection = \"runge-kutta\")")
    parser.add_argument("--interleaved", type=int, metavar="N",
                        help="both in one process, in N alternating chunks of --flow time units (no memory)")
    parser.add_argument("--child", choices=sorted(SCENES), help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULT)
    args = parser.parse_args()
    if args.child:
        print(json.dumps(child(args.child, args.relax, args.flow, args.velocity)))
        return
    if args.interleaved is not None:
        if args.interleaved < 2:
            raise SystemExit(f"--interleaved {args.interleaved}: at least 2 chunks (the first is dropped)")
        result = {"machine": common.machine(),
                  "command": " ".join(["python benchmarks/mesh_parity.py", *sys.argv[1:]]),
                  **interleaved(args.relax, args.flow, args.interleaved, args.velocity,
                                ("grid", "mesh") + ("mesh_boxes",) * args.boxes
                                + ("mesh_runge_kutta",) * args.runge_kutta)}
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(result, indent=1) + "\n")
        for kind, ratios in result["meshes"].items():
            print(f"{kind}/grid CPU under flow {ratios['flow_cpu_ratio']:.2f} over {args.interleaved - 1} chunks of "
                  f"{args.flow:g} (per chunk {min(ratios['chunk_ratios']):.2f}–{max(ratios['chunk_ratios']):.2f})")
        return
    kinds = (["grid", "mesh"] + ["mesh_boxes"] * args.boxes + ["mesh_direct"] * args.direct
             + ["mesh_galerkin"] * args.galerkin + ["mesh_runge_kutta"] * args.runge_kutta)
    runs = []
    for repeat in range(args.repeats):
        for kind in kinds:
            command = [sys.executable, __file__, "--child", kind, "--relax", str(args.relax), "--flow",
                       str(args.flow), "--velocity", str(args.velocity)]
            out = subprocess.run(command, env={**os.environ, **THREADS}, capture_output=True, text=True, cwd=ROOT)
            if out.returncode != 0:
                raise SystemExit(f"{kind} failed:\n{out.stderr[-3000:]}")
            runs.append({**json.loads(out.stdout.strip().splitlines()[-1]), "repeat": repeat})
            print(json.dumps(runs[-1]), flush=True)

    def ratio(kind: str, key: str) -> list[float]:
        return [m[key] / g[key] for g in runs if g["kind"] == "grid"
                for m in runs if m["kind"] == kind and m["repeat"] == g["repeat"]]

    ratios = {kind: {"flow_cpu_per_time_unit": ratio(kind, "flow_ms_per_time_unit"),
                     "peak_memory": ratio(kind, "peak_mb")} for kind in kinds[1:]}
    result = {"machine": common.machine(), "relax": args.relax, "flow": args.flow, "velocity": args.velocity,
              "runs": runs, "ratios_to_grid": ratios, "targets": {"flow_cpu_per_time_unit": 3.0, "peak_memory": 2.0}}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    for kind, values in ratios.items():
        cpu = ", ".join(f"{v:.2f}" for v in values["flow_cpu_per_time_unit"])
        print(f"{kind}/grid: CPU per time unit under flow {cpu}; "
              f"peak memory {', '.join(f'{v:.2f}' for v in values['peak_memory'])}")


if __name__ == "__main__":
    main()
