"""The README's table of accuracy and speed, rendered from the benchmarks' result files.

    python benchmarks/summary.py            # rewrite the table in README.md
    python benchmarks/summary.py --print    # print it

Every number comes from a JSON file in benchmarks/results/ (or verification/results/),
written by the command in the row; nothing here is measured. Each row names the commit the
file was measured at: the file's own record (``commit``, or the tree of a same-run
comparison) where it has one, else the commit that last wrote the file (git log). The
machine: the file's ``machine`` record where it has one, else the project's 2-core machine
(the files that predate that record were all measured there). ``tests/test_docs.py`` fails
when README.md and this table disagree.
"""

from __future__ import annotations

import argparse
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
MARKERS = ("<!-- BEGIN generated: summary -->", "<!-- END generated: summary -->")
#: The machine of the files without a ``machine`` record.
PROJECT_MACHINE = "2-core AMD EPYC, 24 GiB, shared"


@dataclass(frozen=True)
class Row:
    """One line of the table: what is measured, from which file, shown how."""

    quantity: str
    path: str                       # relative to the repository
    value: Callable[[dict], str]    # the file's data → the table cell
    command: str


def _percent(x: float) -> str:
    return f"{100 * x:.3g} %"


def _schemes_row(data: dict, label: str) -> dict:
    return next(row for row in data["rows"] if row["label"] == label)


def _time_error(label: str) -> Callable[[dict], str]:
    def cell(data: dict) -> str:
        row = _schemes_row(data, label)
        errors = row["time_errors"]
        return (f"r(t) {_percent(errors['elongation'])}, period {_percent(errors['period'])}; "
                f"{row['seconds']:.3g} CPU s")
    return cell


def _protocol(data: dict) -> str:
    runs = data["runs"]
    minutes = ", ".join(f"{runs[rate]['new']['cpu_s'] / 60:.2f}" for rate in runs)
    peak = max(run["new"]["peak_mb"] for run in runs.values())
    return f"{minutes} CPU-min at γ̇ = {', '.join(f'{float(r):g}' for r in runs)}; peak {peak:.0f} MiB"


def _scaling(data: dict) -> str:
    largest = max(data["by_N"], key=lambda row: row["N"])
    return (f"N^{data['exponents_N']['default_ms_per_time_unit']:.2f} from N = "
            f"{min(r['N'] for r in data['by_N'])} to {largest['N']}; peak {largest['peak_rss_mb']:.0f} MiB at "
            f"N = {largest['N']}")


def _stability(data: list) -> str:
    cases = [row for row in data if row["scheme"] == "fem-adaptive"]
    return f"{sum(row['stable'] for row in cases)} of {len(cases)} cases run to the end (dt up to 100)"


def _mesh_memory(data: dict) -> str:
    samples = data["configurations"]["default"]["samples"]
    (t0, m0, *_), (t1, m1, *counted) = samples[len(samples) // 2], samples[-1]
    budget = f" (caches {max(sample[2] for sample in samples):.0f} MiB at most)" if counted else ""
    peak = data["configurations"]["default"].get("peak_mib")
    return (f"resident {m0:.0f} MiB at t = {t0:g}, {m1:.0f} MiB at t = {t1:g}{budget}"
            + (f", peak {peak:.0f} MiB" if peak is not None else "")
            + f"; flow phase {data['configurations']['default']['flow_cpu_seconds']:.0f} CPU s")


def _tolerance(data: dict) -> str:
    cases = data["cases"]

    slopes = ", ".join(f"{case} {entry['slope']:.2f}"
                       + (f" (its period {entry['period_slope']:.2f})" if "period_slope" in entry else "")
                       for case, entry in cases.items())
    return f"log–log slopes of error against tolerance_t over three decades: {slopes}"


def _protocol_beside(data: dict) -> str:
    run = next(iter(data["runs"].values()))
    new, old = run["new"], run["old"]
    return (f"{new['cpu_s'] / 60:.1f} CPU-min, peak {new['peak_mb']:.0f} MiB; "
            f"{new['cpu_s'] / old['cpu_s']:.3f}× the CPU of {data['trees']['old']['commit']} beside it")


#: Earlier runs of the obstacle protocol alone, shown beside the current code's: one run's CPU
#: time moves by a few percent from run to run on the shared machine
OBSTACLE_ALONE_EARLIER = ("protocol_obstacle_idle.json", "protocol_obstacle_idle_repeat.json",
                          "protocol_obstacle_shapes.json", "protocol_obstacle_residual.json",
                          "protocol_obstacle_single_alone.json", "protocol_obstacle_box_dofs_alone.json",
                          "protocol_obstacle_solves_alone.json", "protocol_obstacle_window_cg.json",
                          "protocol_obstacle_window_cg_alone.json")


#: The same on shaped windows with the Runge–Kutta mesh advection
OBSTACLE_SHAPES_EARLIER = ("protocol_obstacle_shapes_runge_kutta.json",)


def _protocol_alone(data: dict) -> str:
    run = data["runs"]["None"]["new"]

    def earlier(names: tuple[str, ...]) -> str:
        runs = [json.loads((ROOT / "benchmarks" / "results" / name).read_text()) for name in names]
        return ", ".join(f"{d['runs']['None']['new']['cpu_s'] / 60:.1f} at {str(d['trees']['new']['commit'])[:7]} "
                         f"({d['runs']['None']['new']['peak_mb']:.0f} MiB)" for d in runs)
    return (f"{run['cpu_s'] / 60:.1f} CPU-min, peak {run['peak_mb']:.0f} MiB (earlier runs alone, with the "
            f"Runge–Kutta advection: {earlier(OBSTACLE_SHAPES_EARLIER)}; on boxes: {earlier(OBSTACLE_ALONE_EARLIER)})")


def _span(values: list[float], digits: int) -> str:
    """min–max of ``values`` to ``digits`` decimals, one number where they round alike."""
    low, high = f"{min(values):.{digits}f}", f"{max(values):.{digits}f}"
    return low if low == high else f"{low}–{high}"


#: What the mesh kinds of benchmarks/mesh_parity.py are called in the table
MESH_KINDS = {"mesh": "shaped windows", "mesh_boxes": "boxes",
              "mesh_runge_kutta": "shaped windows with the Runge–Kutta advection at every Courant number"}


def _mesh_parity_interleaved(data: dict) -> str:
    kinds = "; ".join(f"{MESH_KINDS.get(kind, kind)} {ratios['flow_cpu_ratio']:.2f}× "
                      f"(chunks {_span(ratios['chunk_ratios'], 1)}×)" for kind, ratios in data["meshes"].items())
    return (f"CPU under flow against the grid's over {data['chunks'] - 1} chunks of {data['chunk']:g} time units: "
            f"{kinds}")


def _mesh_parity(data: dict) -> str:
    cells = []
    for kind, ratios in data["ratios_to_grid"].items():
        cpu, memory = ratios["flow_cpu_per_time_unit"], ratios["peak_memory"]
        cells.append(f"{MESH_KINDS.get(kind, kind)}: CPU per time unit under flow {_span(cpu, 1)}× the grid's in "
                     f"each of {len(cpu)} repeats, peak memory {_span(memory, 2)}×")
    return "; ".join(cells)


ROWS = (
    Row("time error of the default scheme (lattice N = 100, h = 1, one period; against sav2 at dt = 0.25)",
        "benchmarks/results/work_precision_schemes.json", _time_error("FEM adaptive, tolerance_t 0.1"),
        "python benchmarks/work_precision.py --schemes"),
    Row("the same, first-order scheme at dt = 1", "benchmarks/results/work_precision_schemes.json",
        _time_error("FEM euler"), "python benchmarks/work_precision.py --schemes"),
    Row("tolerance proportionality (a disc relaxing, two discs drifting apart, the sheared lattice's r̄(t), "
        "two discs colliding at κ × 10)",
        "benchmarks/results/tolerance.json", _tolerance, "python benchmarks/tolerance.py"),
    Row("the same with the step-doubling estimate (numerics.estimate = \"doubling\", tolerance per time unit; "
        "the cases with flow)",
        "benchmarks/results/tolerance_doubling.json", _tolerance, "python benchmarks/tolerance.py --estimate doubling"),
    Row("lattice under shear (N = 100), CPU per time unit of the shear's steps at the default (no relaxation, "
        "no frames; whole runs: the first two rows)",
        "benchmarks/results/step_time.json",
        lambda d: (f"{d['default_ms_per_time_unit']:.2f} ms; "
                   f"{d['speedup_over_euler_dt_0.1_at_equal_period_error']:.1f}× first order at equal period error"),
        "python benchmarks/step_time.py"),
    Row("the paper's protocol from random discs (relax 2000 + shear 10⁵ time units), one run at a time",
        "benchmarks/results/protocol.json", _protocol, "python benchmarks/protocol.py"),
    Row("cost against the number of particles (default scheme)", "benchmarks/results/scaling.json", _scaling,
        "python benchmarks/scaling.py --repeats 3"),
    Row("stability matrix of the default scheme (still and sheared, μ × 10, κ × 10, h = λ, walls, overlaps)",
        "benchmarks/results/stability.json", _stability, "python benchmarks/stability.py"),
    Row("the random packing on the unstructured straight mesh against the structured channel (Poiseuille, "
        "N = 100, dt = 10), each run its own process, alternating",
        "benchmarks/results/mesh_parity_processes.json", _mesh_parity,
        "python benchmarks/mesh_parity.py --relax 400 --flow 1600 --repeats 3 --boxes "
        "--output benchmarks/results/mesh_parity_processes.json"),
    Row("the same suspensions in one process, their flows in rotating chunks",
        "benchmarks/results/mesh_parity_shapes.json", _mesh_parity_interleaved,
        "python benchmarks/mesh_parity.py --relax 400 --flow 100 --interleaved 25 --boxes --runge-kutta "
        "--output benchmarks/results/mesh_parity_shapes.json"),
    Row("the same at centre-line velocity 1 (Poiseuille rate 1; on the mesh 3.3 lengths a substep, semi-Lagrangian "
        "steps, shapes swept along the motion)",
        "benchmarks/results/mesh_parity_shapes_velocity1.json", _mesh_parity_interleaved,
        "python benchmarks/mesh_parity.py --relax 400 --flow 100 --interleaved 13 --boxes --runge-kutta "
        "--velocity 1 --output benchmarks/results/mesh_parity_shapes_velocity1.json"),
    Row("the paper's protocol on the meshed obstacle channel (examples/obstacle_mesh.toml: relax 2000 + Stokes "
        "flow 10⁵ time units, dt = 10), box windows, two trees at once on the 2 cores",
        "benchmarks/results/protocol_obstacle_window_cg_both.json", _protocol_beside,
        "python benchmarks/protocol.py --old TREE --scene obstacle_mesh.toml --rates none "
        "--output protocol_obstacle_window_cg_both.json"),
    Row("the same protocol, one run, shaped windows, Taylor–Galerkin advection",
        "benchmarks/results/protocol_obstacle_shaped_windows.json",
        _protocol_alone,
        "python benchmarks/protocol.py --scene obstacle_mesh.toml --rates none "
        "--output protocol_obstacle_shaped_windows.json"),
    Row("meshed obstacle channel (examples/obstacle_mesh.toml, dt = 10, relaxed 200, then 10⁵ of Stokes flow), "
        "memory under flow; the flow's CPU from the end of the relaxation, its set-up included",
        "benchmarks/results/mesh_memory_shapes.json", _mesh_memory,
        "python benchmarks/mesh_memory.py --stokes-time 100000 --allocator default --output mesh_memory_shapes.json"),
)


def measured_at(path: Path, data) -> str:
    """The commit a result file was measured at (see the module docstring)."""
    if isinstance(data, dict):
        commit = data.get("commit") or data.get("trees", {}).get("new", {}).get("commit")
        if commit:  # "+changes": the run's femphase/ differed from that commit (benchmarks/protocol.py)
            commit = str(commit)
            return commit[:7] + ("+changes" if commit.endswith("+changes") else "")
    done = subprocess.run(["git", "log", "-1", "--format=%h", "--", str(path)], cwd=ROOT,
                          capture_output=True, text=True)
    return done.stdout.strip() or "uncommitted"


def machine(data) -> str:
    return str(data.get("machine", PROJECT_MACHINE)) if isinstance(data, dict) else PROJECT_MACHINE


def table() -> str:
    lines = ["| quantity | measured | command | file, commit |", "|---|---|---|---|"]
    machines = set()
    for row in ROWS:
        path = ROOT / row.path
        data = json.loads(path.read_text())
        machines.add(machine(data))
        lines.append(f"| {row.quantity} | {row.value(data)} | `{row.command}` | "
                     f"[{Path(row.path).name}]({row.path}), {measured_at(path, data)} |")
    lines += ["", f"Machine: {'; '.join(sorted(machines))}."]
    return "\n".join(lines)


def with_table(document: str, rendered: str) -> str:
    begin, end = MARKERS
    head, found, rest = document.partition(begin)
    if not found:
        raise ValueError(f"README.md has no {begin!r} marker")
    _, _, tail = rest.partition(end)
    return f"{head}{begin}\n{rendered}\n{end}{tail}"


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--print", action="store_true", help="print the table instead of rewriting README.md")
    if parser.parse_args().print:
        print(table())
    else:
        README.write_text(with_table(README.read_text(), table()))
        print(f"wrote the table into {README}")
