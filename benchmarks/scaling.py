"""Cost against the number of particles N and the mesh spacing h, peak memory, and a profile.

    python benchmarks/scaling.py [--quick] [--repeats R]

* N = 100, 400, 1600 (``--quick``: 100, 400) on hexagonal lattices at the paper's density in
  channels grown in both directions: 70 × 240 (the paper's), 140 × 480, 280 × 960, h = 1,
  each in its own subprocess (so the peak memory, the maximum resident set size, is its
  own). Each is relaxed 100 time units at dt = 1 (windows reach their working size), then
  sheared at the paper's velocity gradient (u = 0.1487·y/240 whatever Ly):
  ``euler_ms_per_step``, the first-order scheme at dt = 1 (median over ``STEPS`` steps);
  ``default_ms_per_time_unit``, the default scheme (numerics defaults, outer step
  ``FRAME``, in calls of ``common.EXAMPLE_CALL`` steps as the examples take them) over
  ``SHEAR_TIME`` time units; ``frame_ms``, a frame with every observable
  (shape, energy, order) and the field data of fields.xdmf (`femphase.io.fields.point_data`).
  Frames compute energies and field data window by window, so they should grow linearly
  in N (dense N × nodes arrays would take ~10 GB at N = 1600).
* h = 2, 1, 0.5 for the paper's N = 100 scene, first-order scheme at dt = 1.

``--repeats R``: every size R times, in the order 100, 400, 1600, 1600, 400, 100, …; the
rows are the medians (peak memory: the largest). On this shared machine one run's exponent
moves by ±0.05 with the load (1.03, 1.08, 1.09 for the same code in three runs), as much
as the gap between N^1.0 and N^1.05.

The first shear step (factorisations) is not timed. Times are CPU seconds of the process
(less disturbed by the other processes on the shared machine than wall time). Exponents
are least-squares slopes of log(cost) against log N and log(1/h).

The profile (cProfile, ``PROFILE_STEPS`` shear steps of benchmarks/step_time.py's scenario:
N = 100, h = 1, first-order scheme at dt = 1, γ̇ = 0.1487) splits the step into its parts.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.scene import scene_from_dict
from femphase.run.simulation import Simulation
from femphase.timestepping.stepper import Stepper

from common import EXAMPLE_CALL, markdown_table, update_readme
from step_time import step_ms

RESULTS = Path(__file__).parent / "results"
PAPER_RATE, PAPER_LY = 0.1487, 240.0
PROFILE_STEPS = 300
SIZES = (100, 400, 1600)
#: SHEAR_TIME: 1000 time units; over 100 (300 ms of N = 100's shear) the
#: medians of three of N = 100 ranged over 0.73–1.18 ms per time unit between runs and the
#: exponent over 1.06–1.17, where 1000 gave 1.18 and 1.30 at N = 100 and 21.4 and 21.3 at
#: N = 1600 in interleaved runs (N^1.03)
STEPS, SHEAR_TIME, FRAME = 20, 1000.0, 10.0


def grown_channel(n: int, h: float = 1.0):
    """N particles at the paper's density: Lx = 70, Ly = 2.4 N, 5 per row (the h sweep)."""
    return scene_from_dict({
        "name": f"scaling N = {n}", "domain": {"Lx": 70.0, "Ly": 2.4 * n, "h": h},
        "particles": {"layout": "hexagonal", "N": n, "per_row": 5}, "output": {"fields": False},
        "numerics": {"scheme": "euler"},
        "phases": [{"name": "shear", "duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                    "flow": {"type": "shear", "rate": PAPER_RATE / PAPER_LY, "scale": "shear_rate"}}],
    })


def square_channel(n: int):
    """N particles at the paper's density in a channel grown in both directions (N = 100·k²:
    70k × 240k, 5k per row), default numerics."""
    scale = int(round(np.sqrt(n / 100)))
    return scene_from_dict({
        "name": f"scaling N = {n}", "domain": {"Lx": 70.0 * scale, "Ly": PAPER_LY * scale},
        "particles": {"layout": "hexagonal", "N": n, "per_row": 5 * scale},
        "output": {"fields": True, "observables": ["shape", "energy", "order"]},
        "phases": [{"duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                    "flow": {"type": "shear", "rate": PAPER_RATE / PAPER_LY, "scale": "shear_rate"}}],
    })


def sheared_stepper(scene, relax_steps: int = 100, **numerics):
    """(state relaxed for ``relax_steps`` at dt = 1 by the first-order scheme, the shear
    stepper after its first step); ``numerics`` overrides the scene's for the shear."""
    simulation = Simulation(scene)
    state = scene.initial_state()
    relax = Stepper(simulation.domain, scene.model, replace(scene.numerics, scheme="euler"), 1.0, None, state.radii)
    for _ in range(relax_steps):
        relax.step(state)
    phase = scene.phases[0]
    stepper = Stepper(simulation.domain, scene.model, replace(scene.numerics, **numerics), phase.dt,
                      scene.flow(phase), state.radii)
    stepper.step(state)  # builds the factorisations: set-up, not per-step cost
    return state, stepper, simulation


def time_per_step(scene, steps: int) -> dict:
    state, stepper, _ = sheared_stepper(scene)
    samples = step_ms(stepper, state, steps, time.process_time)
    return {"N": state.n_particles, "h": scene.domain.spacing, "Ly": scene.domain.width, "steps": steps,
            "nodes": scene.domain.grid.n_nodes, "window_dofs": int(sum(f.size for f in state.fields)),
            "ms_per_step": float(np.median(samples)), "mean_ms": float(np.mean(samples))}


def measure_size(n: int, steps: int, shear_time: float) -> dict:
    """The by-N row of one size (run in a subprocess: its peak memory is its own)."""
    from femphase.io.fields import point_data
    from femphase.run.simulation import Frame
    from femphase.config import Numerics

    scene = square_channel(n)
    state, stepper, simulation = sheared_stepper(scene, scheme="euler")
    euler = step_ms(stepper, state, steps, time.process_time)
    default = Numerics()
    phase = replace(scene.phases[0], dt=FRAME)
    stepper = Stepper(simulation.domain, scene.model, scene.numerics, FRAME, scene.flow(phase), state.radii)
    stepper.step(state)  # set-up
    counted = state.memory["adaptive_counts"].copy()
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    shear = 1e-3 * float(step_ms(stepper, state, round(shear_time / (FRAME * EXAMPLE_CALL)), time.process_time,
                                 EXAMPLE_CALL).sum())
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    substeps = int(state.memory["adaptive_counts"][0] - counted[0])
    frames = []
    for _ in range(3):
        started = time.process_time()
        frame = Frame(state, phase)
        for name in ("shape", "energy", "order"):
            observable = simulation.observable(name)
            values = observable(state, frame.particle)
            frame.particle.update({c: values[c] for c in observable.particle_columns})
        point_data(state, per_particle=False)
        frames.append(time.process_time() - started)
    return {"N": n, "domain": f"{scene.domain.period:g} × {scene.domain.width:g}", "nodes": simulation.domain.n_dofs,
            "window_dofs": int(sum(f.size for f in state.fields)),
            "euler_ms_per_step": float(np.median(euler)),
            "default_scheme": f"{default.scheme} (tolerance_t {default.tolerance_t:g}, outer dt {FRAME:g})",
            "default_ms_per_time_unit": 1e3 * shear / shear_time, "default_substeps": substeps,
            "default_ms_per_substep": 1e3 * shear / max(substeps, 1),
            "default_page_faults_per_time_unit": faults / shear_time,  # minor: memory mapped in again
            "frame_ms": 1e3 * float(np.median(frames)),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def median_row(runs: list[dict]) -> dict:
    """One size's row from its runs: the median of every cost, the largest peak memory, and
    every run's costs (``runs``) when there is more than one."""
    row = dict(runs[-1])
    for key in ("euler_ms_per_step", "default_ms_per_time_unit", "default_ms_per_substep", "frame_ms"):
        row[key] = float(np.median([run[key] for run in runs]))
    row["peak_rss_mb"] = max(run["peak_rss_mb"] for run in runs)
    if len(runs) > 1:
        row["runs"] = [{key: run[key] for key in ("euler_ms_per_step", "default_ms_per_time_unit", "frame_ms")}
                       for run in runs]
    return row


def fitted_exponent(x: np.ndarray, cost: np.ndarray) -> float:
    return float(np.polyfit(np.log(x), np.log(cost), 1)[0])


# -- profile ----------------------------------------------------------------------------------
def profile_parts(steps: int = PROFILE_STEPS) -> dict:
    """Cumulative CPU time of the step's parts over ``steps`` shear steps, in ms per step."""
    state, stepper, _ = sheared_stepper(common.lattice_scene(), scheme="euler")
    profiler = cProfile.Profile()
    profiler.enable()
    for _ in range(steps):
        stepper.step(state)
    profiler.disable()
    stats = pstats.Stats(profiler).stats

    def cumulative(name: str, module: str, caller: str | None = None) -> float:
        total = 0.0
        for (filename, _, function), (_, _, _, ct, callers) in stats.items():
            if function == name and filename.endswith(module):
                if caller is None:
                    total += ct
                else:
                    total += sum(v[3] for (cf, _, cfun), v in callers.items() if cfun == caller)
        return total

    step = cumulative("step", "stepping.py")
    solve = cumulative("solve", "solvers.py")
    # the row shift rebuilds the layout when whole columns move: counted under "layout"
    advect = cumulative("advect", "advection.py")
    advection = (advect - cumulative("layout", "channel.py", caller="advect")
                 - cumulative("group_block", "windows.py", caller="advect"))
    parts = {
        "advection (exact row shift, FFT)": advection,
        "linear solves (tensor-product solver, multi-RHS)": solve,
        # the relaxation of the time scheme (schemes.py: advance) less its advection and solves
        "explicit forces (g, areas, overlaps) and right-hand sides": cumulative("advance", "schemes.py")
        - advect - solve,
        "blow-up check": cumulative("check_fields", "stepping.py"),
        "window refit (misfits, fit, transfer)": cumulative("misfits", "windows.py", caller="refit")
        + cumulative("fit", "windows.py") + cumulative("transfer", "windows.py"),
        "layout (grouping, gather, scatter)": cumulative("layout", "channel.py")
        + cumulative("gather", "windows.py") + cumulative("scatter", "windows.py")
        + cumulative("group_block", "windows.py"),
    }
    parts["other (Python overhead of step)"] = step - sum(parts.values())
    return {"steps": steps, "total_ms": 1e3 * step / steps,
            "parts_ms": {k: 1e3 * v / steps for k, v in parts.items()}}


# -- report -----------------------------------------------------------------------------------
def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.8))
    sizes = np.array([r["N"] for r in result["by_N"]], float)
    for key, label in (("euler_ms_per_step", "first order, ms per step (dt = 1)"),
                       ("default_ms_per_time_unit", "default scheme, ms per time unit"),
                       ("frame_ms", "frame, ms")):
        cost = np.array([r[key] for r in result["by_N"]])
        axes[0].loglog(sizes, cost, "o-", label=f"{label}: N^{fitted_exponent(sizes, cost):.2f}")
    axes[0].loglog(sizes, sizes / sizes[0] * result["by_N"][0]["euler_ms_per_step"], "k:", label="∝ N")
    axes[0].set_xlabel("particles N (paper's density, h = 1)")
    axes[0].set_ylabel("CPU ms")
    rows = result["by_h"]
    x = np.array([1.0 / r["h"] for r in rows])
    y = np.array([r["ms_per_step"] for r in rows])
    axes[1].loglog(x, y, "o-", label=f"slope {result['exponent_h']:.2f}")
    axes[1].set_xlabel("1/h (N = 100, first order, dt = 1)")
    axes[1].set_ylabel("CPU ms per step")
    for ax in axes:
        ax.legend(fontsize=7)
        ax.grid(True, which="both", alpha=0.3)
    fig.suptitle("femphase cost against N and h (shear, windows)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def report(result: dict) -> str:
    rows = [[r["N"], r["domain"], f"{r['nodes']:,}", f"{r['window_dofs']:,}", f"{r['euler_ms_per_step']:.3g}",
             f"{r['default_ms_per_time_unit']:.3g}", r.get("default_substeps", "–"),
             f"{r['frame_ms']:.3g}", f"{r['peak_rss_mb']:.0f}"]
            for r in result["by_N"]]
    table = markdown_table(["N", "channel", "mesh nodes", "window dofs (all)", "first order, ms/step (dt = 1)",
                            f"default ({result['by_N'][0]['default_scheme']}), ms per time unit",
                            "its accepted substeps", "ms per frame", "peak memory (MiB)"], rows)
    exponents = result["exponents_N"]
    h_rows = [[f"{r['h']:g}", f"{r['nodes']:,}", f"{r['window_dofs']:,}", f"{r['ms_per_step']:.3g}"]
              for r in result["by_h"]]
    profile = result["profile"]
    parts = [[name, f"{ms:.2f}", f"{ms / profile['total_ms']:.0%}"] for name, ms in
             sorted(profile["parts_ms"].items(), key=lambda item: -item[1])]
    parts.append(["**step (total, under cProfile)**", f"{profile['total_ms']:.2f}", "100%"])
    repeats = result.get("repeats", 1)
    medians = f"medians of {repeats} runs per size, " if repeats > 1 else ""
    return (f"{table}\n\nFitted exponents ({medians}from N = {rows[0][0]} to {rows[-1][0]}): first order per step "
            f"N^{exponents['euler_ms_per_step']:.2f}, default scheme per time unit "
            f"N^{exponents['default_ms_per_time_unit']:.2f}, frames N^{exponents['frame_ms']:.2f} (target ≤ 1.05); "
            f"peak memory at N = {rows[-1][0]}: {rows[-1][-1]} MiB (target < 1500 MB, i.e. 1431 MiB).\n\n"
            + markdown_table(["h (N = 100)", "mesh nodes", "window dofs (all)", "first order, ms/step (dt = 1)"],
                             h_rows)
            + f"\n\ncost ∝ h^-{result['exponent_h']:.2f} over h = 2 … 0.5.\n\n![scaling](results/scaling.png)\n\n"
            f"Profile of the first-order step (N = 100, h = 1, dt = 1, γ̇ = 0.1487; cProfile over "
            f"{profile['steps']} shear steps, CPU ms per step; cProfile's own overhead inflates the many "
            f"small Python calls):\n\n" + markdown_table(["part", "ms/step", "share"], parts))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="N ≤ 400 and h ∈ {2, 1} only")
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    parser.add_argument("--repeats", type=int, default=1,
                        help="runs per size (sizes up, then down, …); rows are the medians")
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # the subprocess's size
    args = parser.parse_args()
    if args.one:
        print(json.dumps(measure_size(args.one, STEPS, SHEAR_TIME)))
        return
    if args.report:
        update_readme("scaling", report(json.loads((RESULTS / "scaling.json").read_text())))
        return
    started = time.process_time()
    sizes = SIZES[:2] if args.quick else SIZES
    runs: dict[int, list[dict]] = {n: [] for n in sizes}
    for repeat in range(args.repeats):  # up, down, up, …: each size sees early and late load alike
        for n in sizes if repeat % 2 == 0 else sizes[::-1]:
            output = subprocess.run([sys.executable, __file__, "--one", str(n)], check=True, capture_output=True,
                                    text=True).stdout
            runs[n].append(json.loads(output.strip().splitlines()[-1]))
            print(runs[n][-1], flush=True)
    by_n = [median_row(runs[n]) for n in sizes]
    spacings = (2.0, 1.0) if args.quick else (2.0, 1.0, 0.5)
    by_h = []
    for h in spacings:
        by_h.append(time_per_step(grown_channel(100, h), steps=60 if h >= 1 else 20))
        print(by_h[-1], flush=True)
    sizes = np.array([r["N"] for r in by_n], float)
    result = {"by_N": by_n, "by_h": by_h, "repeats": args.repeats,
              "exponents_N": {key: fitted_exponent(sizes, np.array([r[key] for r in by_n]))
                              for key in ("euler_ms_per_step", "default_ms_per_time_unit", "frame_ms")},
              "exponent_h": -fitted_exponent(np.array(spacings), np.array([r["ms_per_step"] for r in by_h])),
              "profile": profile_parts(100 if args.quick else PROFILE_STEPS),
              "command": "python benchmarks/scaling.py" + (" --quick" if args.quick else "")
              + (f" --repeats {args.repeats}" if args.repeats > 1 else "")}
    # the subprocesses' CPU is not this process's: their timed parts are in the rows
    result["cpu_seconds"] = time.process_time() - started
    RESULTS.mkdir(exist_ok=True)
    markdown = report(result)
    print(markdown)
    if not args.quick:
        (RESULTS / "scaling.json").write_text(json.dumps(result, indent=1) + "\n")
        plot(result, RESULTS / "scaling.png")
        update_readme("scaling", markdown)
    print(f"{result['cpu_seconds'] / 60:.1f} CPU-min in this process")


if __name__ == "__main__":
    main()
