"""Shared set-up for the benchmarks: pinned BLAS threads and the paper's lattice scene."""

import os

# BLAS/OpenMP threads oversubscribe the 2-core reference machine (3–10× slower seen); numba's
# too, for any parallel loop (femphase compiles none)
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_name] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import re  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import replace  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Callable  # noqa: E402

import numpy as np  # noqa: E402

from femphase.scene import load_scene, scene_from_dict  # noqa: E402
from femphase.run.simulation import Simulation  # noqa: E402

README = Path(__file__).parent / "README.md"
RANDOM_SCENE = Path(__file__).parents[1] / "examples" / "random.toml"


#: Steps per stepper call in the default scheme's runs: the examples' (their "order"
#: observable looks for T1s every 20 time units, so Simulation.run ends its calls of the
#: adaptive scheme's steps of 10 every 2 steps; benchmarks/merged_steps.py)
EXAMPLE_CALL = 2

def relaxed_random_packing(dt: float | None = None, **numerics):
    """(scene, simulation, state, CPU seconds): examples/random.toml (the paper's Fig. 1a
    set-up, seed 1) after its relaxation phase, at the default scheme and step unless
    ``numerics`` (scene ``[numerics]`` keys) and ``dt`` say otherwise."""
    scene = load_scene(RANDOM_SCENE)
    if numerics:
        scene = replace(scene, numerics=replace(scene.numerics, **numerics))
    phase = scene.phases[0] if dt is None else replace(scene.phases[0], dt=dt)
    simulation = Simulation(scene)
    state = scene.initial_state()
    stepper = simulation.stepper(phase, state.radii)
    started = time.process_time()
    for _ in range(phase.n_steps):
        stepper.step(state)
    return scene, simulation, state, time.process_time() - started


def phase_substeps(memory: dict, phase: int, duration: float) -> dict:
    """The adaptive scheme's accepted substeps in ``phase`` (of ``duration`` time units) and
    their mean size, from a state's memory (``adaptive_phase_counts``); empty for fixed-step
    schemes."""
    counts = memory.get("adaptive_phase_counts")
    if counts is None or counts.shape[0] <= phase:
        return {}
    accepted = int(counts[phase, 0])
    return {"substeps": accepted, "mean_substep": duration / accepted}


def machine() -> str:
    """This machine as the results record it: cores, CPU model and memory (Linux)."""
    model, memory = "unknown CPU", None
    try:
        cpuinfo = Path("/proc/cpuinfo").read_text()
        model = next(line.split(":", 1)[1].strip() for line in cpuinfo.splitlines() if line.startswith("model name"))
        kib = next(int(line.split()[1]) for line in Path("/proc/meminfo").read_text().splitlines()
                   if line.startswith("MemTotal"))
        memory = round(kib / 2**20)
    except (OSError, StopIteration, ValueError):
        pass
    return f"{os.cpu_count()}-core {model}" + (f", {memory} GiB" if memory else "") + ", shared"


def run_phases(scene):
    """(state, CPU seconds per phase, batched CG iterations per phase (in products with the whole
    layout's matrix, :attr:`~femphase.timestepping.stepper.Stepper.krylov_iterations`), the last phase's
    stepper): every phase of ``scene`` from its initial state, each in one stepper call
    (the adaptive scheme merges its steps) with its scheme started as ``Simulation.run``
    starts a phase; CPU is the process clock around the call."""
    simulation = Simulation(scene)
    state = scene.initial_state()
    cpu, iterations = [], []
    for phase in scene.phases:
        stepper = simulation.stepper(phase, state.radii)
        stepper.scheme.start_phase(state)
        started = time.process_time()
        stepper.step(state, phase.n_steps)
        cpu.append(time.process_time() - started)
        iterations.append(round(float(getattr(stepper, "krylov_iterations", 0)), 1))
    return state, cpu, iterations, stepper


def relaxed_flow(scene):
    """(state, stepper): ``scene``'s initial state relaxed through its first phase in one
    stepper call, and the second phase's stepper with its scheme started, ready to step the
    flow in chunks (``stepper.step(state, n)``), as the interleaved benchmarks do."""
    simulation = Simulation(scene)
    state = scene.initial_state()
    relaxation, flowing = scene.phases[:2]
    stepper = simulation.stepper(relaxation, state.radii)
    stepper.scheme.start_phase(state)
    stepper.step(state, relaxation.n_steps)
    stepper = simulation.stepper(flowing, state.radii)
    stepper.scheme.start_phase(state)
    return state, stepper


STRAIGHT_MESH_SCENE = Path(__file__).parents[1] / "examples" / "straight_mesh.toml"


def straight_mesh_variant(variant: str, relax: float, flow: float, output: Path, flow_dt: float = 10.0,
                          sets: tuple[str, ...] = ()) -> dict:
    """One variant of examples/straight_mesh.toml (dt = 10 unless ``flow_dt`` sets the flow
    phase's, ``sets`` further overrides) relaxed ``relax`` and run ``flow`` time units under
    its Stokes flow by :func:`run_phases`; its end state goes to ``output``
    (:func:`save_end_state`). The record of a variant script's child (:func:`variant_runs`)."""
    scene = load_scene(STRAIGHT_MESH_SCENE, ["phases.0.dt=10.0", f"phases.1.dt={flow_dt}",
                                             f"phases.0.duration={relax}", f"phases.1.duration={flow}",
                                             "output.fields=false", *sets])
    state, cpu, iterations, stepper = run_phases(scene)
    save_end_state(state, stepper, output)
    return {"variant": variant, "cpu_s": cpu, "cg_iterations": iterations,
            "positions": int(sum(field.size for field in state.fields)), "period": float(stepper.domain.period)}


def save_end_state(state, stepper, output: Path) -> None:
    """Every particle's field on the whole domain (zero outside its window), its centroid and
    its area at the end of a run, to ``output`` (.npz), for :func:`differences`."""
    layout, phi = state.flat()
    fields = np.zeros((len(layout.windows), stepper.domain.n_dofs))
    fields[layout.owner, layout.node_index] = phi
    areas, centroids, _ = stepper.domain.shape_moments(layout, phi)
    np.savez(output, fields=fields, centroids=centroids, areas=areas)


def differences(reference: Path, other: Path, period: float) -> dict:
    """Largest differences of ``other`` from ``reference`` (:func:`save_end_state`): φ,
    centroid (periodic in x), area (relative)."""
    a, b = np.load(reference), np.load(other)
    shift = b["centroids"] - a["centroids"]
    shift[:, 0] = (shift[:, 0] + 0.5 * period) % period - 0.5 * period
    return {"max_phi": float(np.abs(a["fields"] - b["fields"]).max()),
            "max_centroid": float(np.abs(shift).max()),
            "max_relative_area": float(np.max(np.abs(b["areas"] - a["areas"]) / a["areas"]))}


def print_differences(runs: dict, against: str, describe: Callable[[dict], str]) -> None:
    """One line per variant compared ``against`` the first (:func:`variant_runs`): what
    ``describe(record)`` says, then its largest differences in φ, a centroid and an area."""
    for variant, run in list(runs.items())[1:]:
        d = run[against]
        print(f"{variant}: {describe(run)}; {against.replace('_', ' ')}: φ {d['max_phi']:.2g}, "
              f"centroid {d['max_centroid']:.2g}, area {d['max_relative_area']:.2g}")


def variant_arguments(description: str, variants: tuple[str, ...], flow: float, result: Path) -> argparse.Namespace:
    """The command line of a script that runs ``variants`` of a mesh run in child processes
    (:func:`variant_runs`): ``--relax``, ``--flow`` (default ``flow``), ``--output``."""
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--relax", type=float, default=400.0, help="time units of relaxation (default 400)")
    parser.add_argument("--flow", type=float, default=flow, help=f"time units of flow (default {flow:g})")
    parser.add_argument("--child", choices=variants, help=argparse.SUPPRESS)
    parser.add_argument("--fields", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=result)
    return parser.parse_args()


def variant_main(script: str, description: str, variants: tuple[str, ...], flow: float, result: Path,
                 child: Callable[[str, float, float, Path], dict], against: str) -> dict | None:
    """The body of a variant script's ``main()``: parse its command line
    (:func:`variant_arguments`); in a child process run ``child(variant, relax, flow,
    fields)`` and print its record, returning None; otherwise run every variant
    (:func:`variant_runs`) and return the records by variant."""
    args = variant_arguments(description, variants, flow, result)
    if args.child:
        print(json.dumps(child(args.child, args.relax, args.flow, args.fields)))
        return None
    return variant_runs(script, variants, args, against)["runs"]


def variant_runs(script: str, variants: tuple[str, ...], args: argparse.Namespace, against: str) -> dict:
    """Run every variant of ``script`` in its own child process (``--child VARIANT``, which
    prints its record as the last line of JSON and saves its end state with
    :func:`save_end_state`), compare every variant after the first with the first under
    ``against`` (:func:`differences`), write the result with its command to ``args.output``
    and return it."""
    scratch = args.output.parent / f"{Path(script).stem}_fields"
    scratch.mkdir(parents=True, exist_ok=True)
    runs = {}
    try:
        for variant in variants:
            out = subprocess.run([sys.executable, script, "--child", variant, "--relax", str(args.relax),
                                  "--flow", str(args.flow), "--fields", str(scratch / f"{variant}.npz")],
                                 capture_output=True, text=True, cwd=Path(script).resolve().parents[1])
            if out.returncode != 0:
                raise SystemExit(f"{variant} failed:\n{out.stderr[-3000:]}")
            runs[variant] = json.loads(out.stdout.strip().splitlines()[-1])
            print(json.dumps(runs[variant]), flush=True)
        for variant in variants[1:]:
            runs[variant][against] = differences(scratch / f"{variants[0]}.npz", scratch / f"{variant}.npz",
                                                 runs[variant]["period"])
    finally:
        for variant in variants:
            (scratch / f"{variant}.npz").unlink(missing_ok=True)
        scratch.rmdir()
    result = {"relax": args.relax, "flow": args.flow, "runs": runs, "load_average": load_average(),
              "command": f"python benchmarks/{Path(script).name} --relax {args.relax:g} --flow {args.flow:g}"}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1) + "\n")
    return result


def random_shear_stepper(scene, simulation, state, rate: float):
    """(stepper, phase): ``scene``'s shear phase (examples/random.toml's second) at ``rate``
    on ``state``, its scheme started as ``Simulation.run`` starts a phase."""
    phase = replace(scene.phases[1], flow={**scene.phases[1].flow, "rate": rate})
    stepper = simulation.stepper(phase, state.radii)
    stepper.scheme.start_phase(state)
    return stepper, phase


def lattice_scene(h: float = 1.0, windows: bool = True, rate: float = 0.1487, **numerics):
    """The paper's N = 100 hexagonal lattice in 70 × 240 under linear shear."""
    return scene_from_dict({
        "name": "benchmark lattice",
        "domain": {"Lx": 70.0, "Ly": 240.0, "h": h},
        "particles": {"layout": "hexagonal", "N": 100},
        "numerics": {"windows": windows, **numerics},
        "output": {"fields": False},
        "phases": [{"name": "shear", "duration": 1.0, "dt": 1.0, "frame_interval": 1.0,
                    "flow": {"type": "shear", "rate": rate}}],
    })


def load_average() -> list[float]:
    """The machine's 1, 5 and 15 minute load averages: the absolute milliseconds mean little
    on a loaded 2-core machine, so results say how loaded it was."""
    return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]


def markdown_table(header: list[str], rows: list[list]) -> str:
    """A GitHub markdown table of already formatted cells."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def update_readme(section: str, text: str) -> None:
    """Replace the generated ``section`` of benchmarks/README.md (between its markers) by
    text; append the section if the README has none yet."""
    begin, end = f"<!-- generated:{section} -->", f"<!-- /generated:{section} -->"
    block = f"{begin}\n{text}\n{end}"
    content = README.read_text() if README.exists() else ""
    pattern = re.compile(re.escape(begin) + ".*?" + re.escape(end), re.S)
    content = pattern.sub(lambda _: block, content) if pattern.search(content) else content + f"\n{block}\n"
    README.write_text(content)
