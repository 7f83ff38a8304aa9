"""Work–precision: CPU time against error for FEM options and the FD reference scheme.

    python benchmarks/work_precision.py [--quick] [--reuse-reference]
    python benchmarks/work_precision.py --schemes [--report]

Two problems, each against a converged reference computed in the same run:

(a) ``particle``: one particle (R = 8) relaxing from R/2 in a 40 × 40 channel, t = 30 (the
    area is then 0.86 πR², still growing). Errors: the area ∫φ² (relative) and max |φ − φ_ref|
    on the nodes of the h = 2 grid (shared by all nested grids h = 2, 1, 0.5, 0.25).
    Reference: Richardson extrapolation in h (O(h²)) of FEM full-mesh runs at h = 0.5 and
    0.25 with dt = 0.01 (time error ~4e-5 relative in area, ≥ 10× below every point).
(b) ``lattice``: the paper's N = 100 hexagonal lattice in 70 × 240 relaxed 300 and sheared
    at γ̇ = 0.1487 for 3600 time units: the first T1 peak of the mean elongation r̄(t) comes
    ~1100 after the onset and the next one period (≈ 1880) later, so the window holds one
    full oscillation period. Errors: ``elongation`` max_t |r̄(t) − r̄_ref(t)| / max_t r̄_ref
    over frames every 10 time units; ``period`` |T − T_ref| / T_ref with T the time between
    the first two primary peaks of r̄(t) in the shear phase
    (:func:`femphase.analysis.periods.first_period`). Reference: FEM h = 0.5,
    dt = 0.2 (the finest run affordable, ~10 CPU-min; no Richardson: only one finer h is).

Times are CPU seconds of this process from the stepper's construction to the end of the
run (factorisations, windows and frame observables included, the mesh assembly not), the
best of up to three repeats for runs under 0.5 s. The same run measures FEM at its
defaults (h = 1, dt = 1, lumped mass, right diagonals, windows, direct solver) and the FD
reference at the paper's h = 1, dt = 0.1: ``speedup_vs_fd`` is the ratio of their times
when every FEM error of the lattice (r(t) and period) is at most the FD's; otherwise the
cheapest FEM point at or below the FD's errors is used (both are reported). These two
sweeps run the first-order scheme ``euler`` unless a point
says otherwise, so the time scheme's order is not a variable there. Every point lists the
command that reproduces it (``femphase run`` on examples/single.toml or
examples/hexagonal.toml with ``--set``).

``--schemes``: the time schemes on the lattice problem (b) at h = 1 — first order
``euler`` at fixed dt, second order ``sav2`` at fixed dt, ``adaptive`` (outer step = the
frame interval 10) at three tolerances. Errors against two references: ``time`` is sav2 at
h = 1, dt = 0.25 computed in this run (the same spatial discretisation, so only the time
error remains; second order, so ~1/16 of sav2's error at dt = 1), ``converged`` the stored
h = 0.5, dt = 0.2 reference of ``results/work_precision.json`` (space and time together).
Points run two at a time (CPU time per process). Writes
``results/work_precision_schemes.json``, ``results/work_precision_schemes.png`` and the
README section; ``--report`` rewrites the section from the JSON.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np

from femphase.analysis.periods import first_period
from femphase.analysis.shape import shape_observables
from femphase.errors import BlowUpError
from femphase.scene import scene_from_dict
from femphase.run.simulation import Simulation, Tracker

from common import markdown_table, update_readme

RESULTS = Path(__file__).parent / "results"
DEFAULT = {"method": "fem", "h": 1.0, "dt": 1.0, "options": {}}
FRAME = 10.0  # time units between lattice frames (a multiple of every dt used)
PARTICLE_TIME = 30.0
RELAX, SHEAR, RATE = 300.0, 3600.0, 0.1487


@dataclass
class Point:
    """One run: method, spacing, step, numerics options; filled with time and result."""

    problem: str
    method: str
    h: float
    dt: float
    options: dict = field(default_factory=dict)
    seconds: float = 0.0
    result: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    failure: str = ""  # the BlowUpError's message of a run that did not finish
    frame: float = FRAME  # time units between the lattice's frames

    @property
    def label(self) -> str:
        if self.method == "fd":
            return "FD (Heun)"
        names = {"mass": "{} mass", "diagonals": "{} diagonals", "windows": "windows {}",
                 "solver": "{}", "tolerance": "tol {:g}", "scheme": "{}", "tolerance_t": "tolerance_t {:g}",
                 "repulsion_split": "{} repulsion", "area_implicit": "{} area mode", "precision": "{} precision",
                 "estimate": "{} estimate"}
        switches = {"repulsion_split": ("split", "unsplit"), "area_implicit": ("implicit", "explicit")}
        parts = [names[k].format(dict(zip((True, False), switches.get(k, ("on", "off")))).get(v, v))
                 for k, v in sorted(self.options.items())]
        return "FEM " + (", ".join(parts) if parts else "default")

    @property
    def numerics(self) -> dict:
        """The scene's numerics table: the options, with the first-order scheme unless they
        name one (module docstring)."""
        return {"scheme": "euler", **self.options} if self.method == "fem" else dict(self.options)

    @property
    def is_default(self) -> bool:
        return self.method == "fem" and self.h == 1.0 and self.dt == 1.0 and not self.options

    def command(self) -> str:
        """The femphase CLI call that runs this point (plus field output, which the timed run skips)."""
        if self.problem == "particle":
            sets = ["domain.Lx=40.0", "domain.Ly=40.0", "'particles.centres=[[20.0,20.0]]'",
                    f"'phases=[{{name=\"relax\",duration={PARTICLE_TIME:g}.0,dt={self.dt:g},"
                    f"frame_interval={PARTICLE_TIME:g}.0}}]'"]
            scene = "examples/single.toml"
        else:
            sets = [f"phases.{i}.{key}={value:g}" for i, duration in enumerate((RELAX, SHEAR))
                    for key, value in (("duration", duration), ("frame_interval", self.frame), ("dt", self.dt))]
            scene = "examples/hexagonal.toml"
        sets += [f"domain.h={self.h:g}"] + [f"numerics.{k}={json.dumps(v)}" for k, v in sorted(self.numerics.items())
                                            if self.method == "fem"]
        method = " --method fd" if self.method == "fd" else ""
        return f"femphase run {scene} -o out{method} " + " ".join(f"--set {s}" for s in sets)


def scene_for(point: Point):
    tables = {"name": f"work-precision {point.problem}", "numerics": point.numerics, "output": {"fields": False}}
    if point.problem == "particle":
        return scene_from_dict({
            **tables, "domain": {"Lx": 40.0, "Ly": 40.0, "h": point.h},
            "particles": {"layout": "single", "centres": [[20.0, 20.0]]},
            "phases": [{"name": "relax", "duration": PARTICLE_TIME, "dt": point.dt, "frame_interval": PARTICLE_TIME}],
        })
    return scene_from_dict({
        **tables, "domain": {"Lx": 70.0, "Ly": 240.0, "h": point.h},
        "particles": {"layout": "hexagonal", "N": 100},
        "phases": [{"name": "relax", "duration": RELAX, "dt": point.dt, "frame_interval": point.frame},
                   {"name": "shear", "duration": SHEAR, "dt": point.dt, "frame_interval": point.frame,
                    "flow": {"type": "shear", "rate": RATE}}],
    })


class MeanElongation(Tracker):
    """Times and mean elongation at the frames."""

    needs = frozenset({"shape"})

    def __init__(self) -> None:
        self.times: list[float] = []
        self.values: list[float] = []

    def frame(self, frame) -> None:
        self.times.append(frame.state.time)
        self.values.append(float(np.mean(frame.shape.elongation)))


def run(point: Point) -> Point:
    """Run ``point`` (timed) and store its observables in point.result."""
    scene = scene_for(point)
    simulation = Simulation(scene, point.method)
    times = []
    while True:
        state = scene.initial_state()
        tracker = MeanElongation()
        started = time.process_time()
        try:
            simulation.run(state, [tracker])
        except BlowUpError as exc:
            point.failure = str(exc)
            print(f"{point.problem:<8} {point.label:<36} h={point.h:<5g} dt={point.dt:<7g} {exc}", flush=True)
            return point
        times.append(time.process_time() - started)
        if times[-1] > 0.5 or len(times) == 3:
            break
    point.seconds = min(times)
    if point.problem == "particle":
        stride = round(2.0 / point.h)  # the h = 2 grid's nodes
        grid = state.domain.grid
        phi = state.global_field(0).reshape(grid.ny, grid.nx)[::stride, ::stride]
        point.result = {"area": float(shape_observables(state).area[0]),
                        "field": phi.tolist()}
    else:
        point.result = {"times": tracker.times, "mean_elongation": tracker.values}
        shear = common.phase_substeps(state.memory, 1, SHEAR)
        if shear:  # the adaptive scheme's substeps under shear
            point.result["shear_substeps"] = shear
    print(f"{point.problem:<8} {point.label:<36} h={point.h:<5g} dt={point.dt:<7g} {point.seconds:8.2f} s", flush=True)
    return point


# -- references ----------------------------------------------------------------------------------
def particle_reference() -> dict:
    """Richardson (O(h²)) of full-mesh FEM runs at h = 0.5, 0.25 with dt = 0.01."""
    fine, coarse = (run(Point("particle", "fem", h, 0.01, {"windows": False})) for h in (0.25, 0.5))
    extrapolate = lambda f, c: f + (f - c) / 3.0  # noqa: E731
    return {
        "area": extrapolate(fine.result["area"], coarse.result["area"]),
        "field": extrapolate(np.array(fine.result["field"]), np.array(coarse.result["field"])).tolist(),
        "richardson_correction_area": abs(fine.result["area"] - coarse.result["area"]) / 3.0,
        "seconds": fine.seconds + coarse.seconds,
    }


def lattice_reference() -> dict:
    point = run(Point("lattice", "fem", 0.5, 0.2))
    return {**point.result, "seconds": point.seconds}


def particle_errors(point: Point, reference: dict) -> dict:
    return {"area": abs(point.result["area"] - reference["area"]) / reference["area"],
            "field": float(np.max(np.abs(np.array(point.result["field"]) - np.array(reference["field"]))))}


def lattice_errors(point: Point, reference: dict) -> dict:
    r, r_ref = np.array(point.result["mean_elongation"]), np.array(reference["mean_elongation"])
    times = np.array(reference["times"])
    assert np.allclose(point.result["times"], times)
    shear = times >= RELAX
    period, period_ref = first_period(times[shear], r[shear]), first_period(times[shear], r_ref[shear])
    return {"elongation": float(np.max(np.abs(r - r_ref)) / np.max(np.abs(r_ref))),
            # a run without two peaks has not oscillated: its period error is total
            "period": float(abs(period - period_ref) / period_ref) if np.isfinite(period) else 1.0}


# -- the sweeps ----------------------------------------------------------------------------------
def particle_points(quick: bool) -> list[Point]:
    dts = (0.1, 0.3, 1.0, 3.0)
    points = [Point("particle", "fem", h, dt) for h in ((2.0, 1.0) if quick else (2.0, 1.0, 0.5, 0.25)) for dt in dts]
    points += [Point("particle", "fd", h, dt) for h, dt in ((2.0, 0.4), (1.0, 0.1), (0.5, 0.025), (0.25, 0.00625))
               if not (quick and h < 1)]
    if quick:
        return points
    for h in (1.0, 0.5):
        points += [Point("particle", "fem", h, dt, {"mass": "consistent"}) for dt in dts]
        points += [Point("particle", "fem", h, dt, {"diagonals": "alternating"}) for dt in (0.3, 1.0, 3.0)]
        points += [Point("particle", "fem", h, dt, {"windows": False}) for dt in (0.3, 1.0)]
        points += [Point("particle", "fem", h, 1.0, {"solver": "amg", "tolerance": tol}) for tol in (1e-4, 1e-6, 1e-10)]
    return points


def lattice_points(quick: bool) -> list[Point]:
    if quick:
        return [Point("lattice", "fem", 1.0, dt) for dt in (1.0, 2.5)] + [Point("lattice", "fem", 2.0, 1.0)]
    points = [Point("lattice", "fem", h, dt) for h, dts in ((2.0, (1.0, 2.5)), (1.0, (0.25, 0.5, 1.0, 2.5)),
                                                           (0.5, (1.0, 2.5))) for dt in dts]
    points += [Point("lattice", "fem", 1.0, dt, {"mass": "consistent"}) for dt in (1.0, 2.5)]
    points += [Point("lattice", "fem", 1.0, dt, {"diagonals": "alternating"}) for dt in (1.0, 2.5)]
    points += [Point("lattice", "fem", 1.0, 1.0, {"windows": False}), Point("lattice", "fem", 1.0, 1.0, {"solver": "direct"})]
    points += [Point("lattice", "fd", 2.0, 0.4), Point("lattice", "fd", 1.0, 0.1)]
    return points


def pareto_front(points: list[Point], keys: list[str]) -> set[int]:
    """Indices of the points no other point beats in time and in every error of ``keys``."""
    front = set()
    for i, p in enumerate(points):
        beaten = any(q.seconds < p.seconds and all(q.errors[k] < p.errors[k] for k in keys) for q in points)
        if not beaten:
            front.add(i)
    return front


def speedup_vs_fd(points: list[Point], keys: list[str]) -> dict:
    """FD (h = 1, dt = 0.1) time over the cheapest FEM point whose every error in ``keys`` is
    at most the FD's."""
    fd = next(p for p in points if p.method == "fd" and p.h == 1.0 and p.dt == 0.1)
    default = next(p for p in points if p.is_default)
    matching = [p for p in points if p.method == "fem" and all(p.errors[k] <= fd.errors[k] for k in keys)]
    cheapest = min(matching, key=lambda p: p.seconds) if matching else None
    return {
        "errors": keys, "fd_seconds": fd.seconds, "fd_errors": {k: fd.errors[k] for k in keys},
        "default_seconds": default.seconds, "default_errors": {k: default.errors[k] for k in keys},
        "default_speedup": fd.seconds / default.seconds,
        "default_error_ratios": {k: default.errors[k] / fd.errors[k] if fd.errors[k] > 0 else None for k in keys},
        "equal_error_fem": None if cheapest is None else {"label": cheapest.label, "h": cheapest.h, "dt": cheapest.dt,
                                                           "seconds": cheapest.seconds,
                                                           "errors": {k: cheapest.errors[k] for k in keys}},
        "speedup_vs_fd": None if cheapest is None else fd.seconds / cheapest.seconds,
    }


# -- report --------------------------------------------------------------------------------------
def plot(panels: list[tuple[str, list[Point], str]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5 * len(panels), 4.4))
    for ax, (title, points, key) in zip(np.atleast_1d(axes), panels):
        curves: dict[tuple, list[Point]] = {}
        for p in points:
            curves.setdefault((p.label, p.h if p.method == "fem" else None), []).append(p)
        labels = sorted({p.label for p in points})
        colours = {label: plt.cm.tab10(i % 10) for i, label in enumerate(labels)}
        for (label, h), members in curves.items():
            members.sort(key=lambda p: p.seconds)
            x = [p.seconds for p in members]
            y = [max(p.errors[key], 1e-16) for p in members]
            name = label if h is None else f"{label}, h = {h:g}"
            ax.loglog(x, y, "o-" if label != "FD (Heun)" else "s--", color=colours[label],
                      alpha=1.0 if h in (None, 1.0) else 0.55, label=name, markersize=4)
            for p, xi, yi in zip(members, x, y):
                if label != "FD (Heun)" and p.h != 1.0 and p.dt == 1.0:
                    ax.annotate(f"h={p.h:g}", (xi, yi), fontsize=6)
        for p in points:
            if p.is_default:
                ax.loglog(p.seconds, p.errors[key], "*", color="k", markersize=14, label="femphase default")
        ax.set_xlabel("CPU seconds")
        ax.set_ylabel(f"{key} error")
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    # one legend below the panels: inside them it covered the points
    entries = {}
    for ax in np.atleast_1d(axes):
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    rows = -(-len(entries) // 3)
    legend_height = 0.16 * rows + 0.2  # inches
    fig.set_size_inches(5 * len(panels), 4.4 + legend_height)
    fig.legend(list(entries.values()), list(entries), loc="lower center", ncol=3, fontsize=6.5, frameon=False)
    fig.tight_layout(rect=(0, legend_height / (4.4 + legend_height), 1, 1))
    fig.savefig(path, dpi=130)


def table(points: list[Point], keys: list[str]) -> str:
    front = {key: pareto_front(points, [key]) for key in keys}
    rows = []
    for i, p in sorted(enumerate(points), key=lambda item: item[1].seconds):
        marks = "".join("F" if i in front[k] else "·" for k in keys)
        rows.append([p.label + (" **(default)**" if p.is_default else ""), f"{p.h:g}", f"{p.dt:g}", f"{p.seconds:.3g}"]
                    + [f"{p.errors[k]:.2e}" for k in keys] + [marks, f"`{p.command()}`"])
    return markdown_table(["method / options", "h", "dt", "CPU s"] + [f"{k} error" for k in keys]
                          + ["on front (" + ", ".join(keys) + ")", "command"], rows)


def report(result: dict) -> str:
    text = []
    for problem, keys in (("particle", ["area", "field"]), ("lattice", ["elongation", "period"])):
        points = result[f"_{problem}_points"]
        text.append(f"**({'a' if problem == 'particle' else 'b'}) {problem}** — reference computed in "
                    f"{result[problem]['reference_seconds']:.0f} CPU s; F = on the fastest front for that error.\n")
        text.append(table(points, keys))
        for f in result[problem]["failed"]:
            text.append(f"\n- did not finish: {f['label']}, h = {f['h']:g}, dt = {f['dt']:g}: {f['message']} (`{f['command']}`)")
        for group in result[problem]["speedup"]:
            s = result[problem]["speedup"][group]
            equal = s["equal_error_fem"]
            errors = lambda values: ", ".join(f"{k} {v:.2e}" for k, v in values.items())  # noqa: E731
            on_front = result[problem]["default_on_front"]
            fronts = ", ".join(f"{k}: {'yes' if on_front[k] else '**no**'}" for k in s["errors"]) + (
                f"; jointly, no point faster with every error smaller: {'yes' if on_front[group] else '**no**'}"
                if group in on_front else "")
            text.append(
                f"\n- {group}: FEM default {s['default_seconds']:.3g} s (errors {errors(s['default_errors'])}) vs "
                f"FD h = 1, dt = 0.1 {s['fd_seconds']:.3g} s (errors {errors(s['fd_errors'])}): time ratio "
                f"{s['default_speedup']:.1f}×; "
                + (f"cheapest FEM at ≤ FD's errors: {equal['label']} h = {equal['h']:g}, dt = {equal['dt']:g}, "
                   f"{equal['seconds']:.3g} s → **speedup_vs_fd = {s['speedup_vs_fd']:.1f}×**" if equal else
                   "no FEM point reached the FD's errors")
                + f"; default on the fastest front ({fronts}).")
        text.append("")
    text.append("![work-precision](results/work_precision.png)")
    return "\n".join(text)


# -- the time schemes (--schemes) ---------------------------------------------------------------
SCHEME_POINTS = ([Point("lattice", "fem", 1.0, dt, {"scheme": "euler"}) for dt in (1.0, 0.5, 0.25, 0.1)]
                 + [Point("lattice", "fem", 1.0, dt, {"scheme": "sav2"}) for dt in (5.0, 2.5, 1.0)]
                 + [Point("lattice", "fem", 1.0, 2.5, {"scheme": "sav2", "repulsion_split": False})]
                 # the area term's rank-one mode implicit in the predictor
                 + [Point("lattice", "fem", 1.0, dt, {"scheme": "sav2", "area_implicit": True}) for dt in (5.0, 2.5)]
                 + [Point("lattice", "fem", 1.0, FRAME, {"scheme": "adaptive", "tolerance_t": 1e-1, "area_implicit": True})]
                 + [Point("lattice", "fem", 1.0, FRAME, {"scheme": "adaptive", "tolerance_t": tol})
                    for tol in (1e-1, 3e-2, 1e-2)]
                 # the repulsion not split off
                 + [Point("lattice", "fem", 1.0, FRAME, {"scheme": "adaptive", "tolerance_t": 1e-2,
                                                          "repulsion_split": False})])
SCHEMES_OUT = RESULTS / "work_precision_schemes.json"


def scheme_rows(points: list[Point], converged: dict, in_time: dict) -> list[dict]:
    rows = []
    for p in points:
        row = {"label": p.label, "dt": p.dt, "options": p.options, "command": p.command()}
        if p.failure:
            rows.append({**row, "failure": p.failure})
            continue
        rows.append({**row, "seconds": p.seconds, "errors": lattice_errors(p, converged),
                     "time_errors": lattice_errors(p, in_time)})
    return rows


def is_default_scheme(row: dict) -> bool:
    """Whether a row runs the scheme and tolerance a scene gets by default."""
    from femphase.config import Numerics

    defaults = Numerics()
    options = row["options"]
    return (options.get("scheme") == defaults.scheme
            and options.get("tolerance_t", defaults.tolerance_t) == defaults.tolerance_t
            and options.get("repulsion_split", defaults.repulsion_split) == defaults.repulsion_split
            and options.get("area_implicit", defaults.area_implicit) == defaults.area_implicit
            and (defaults.scheme != "adaptive" or row["dt"] == FRAME))


def schemes_report(result: dict) -> str:
    percent = lambda x: f"{100 * x:.2g} %"  # noqa: E731
    rows = []
    for row in result["rows"]:
        name = row["label"].removeprefix("FEM ") + (" **(default)**" if is_default_scheme(row) else "")
        if "failure" in row:
            rows.append([name, f"{row['dt']:g}", "—", "did not finish", "", "", "", f"`{row['command']}`"])
            continue
        t, c = row["time_errors"], row["errors"]
        rows.append([name, f"{row['dt']:g}", f"{row['seconds']:.1f}", percent(t["elongation"]), percent(t["period"]),
                     percent(c["elongation"]), percent(c["period"]), f"`{row['command']}`"])
    return "\n".join([
        f"Lattice over one period at h = 1 (`python benchmarks/work_precision.py --schemes`, "
        f"{result['cpu_seconds'] / 60:.0f} CPU-min); errors **in time** against sav2 at dt = 0.25 "
        f"({result['reference_seconds']:.0f} CPU s), and against the stored h = 0.5 run (**converged**).\n",
        markdown_table(["scheme", "dt", "CPU s", "r(t), in time", "period, in time", "r(t), converged",
                        "period, converged", "command"], rows),
        "", "![time schemes](results/work_precision_schemes.png)"])


def schemes_main(report_only: bool) -> None:
    if report_only:
        update_readme("work_precision_schemes", schemes_report(json.loads(SCHEMES_OUT.read_text())))
        return
    from concurrent.futures import ProcessPoolExecutor

    started = time.process_time()
    converged = json.loads((RESULTS / "work_precision.json").read_text())["lattice"]["reference"]
    reference = Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"})
    # the longest runs first, two processes: the machine's two cores
    with ProcessPoolExecutor(2) as pool:
        done = list(pool.map(run, [reference] + SCHEME_POINTS))
    reference, points = done[0], done[1:]
    result = {"rows": scheme_rows(points, converged, reference.result), "reference_seconds": reference.seconds,
              "reference": "time_errors: sav2 at h = 1, dt = 0.25 (this run); errors: work_precision.json lattice "
                           "reference (h = 0.5, dt = 0.2)",
              "cpu_seconds": time.process_time() - started + sum(p.seconds for p in done),
              "command": "python benchmarks/work_precision.py --schemes"}
    SCHEMES_OUT.write_text(json.dumps(result, indent=1) + "\n")
    finished = [p for p in points if not p.failure]
    for p in finished:
        p.errors = lattice_errors(p, reference.result)
    plot([(f"lattice, h = 1: {k} error in time", finished, k) for k in ("elongation", "period")],
         RESULTS / "work_precision_schemes.png")
    markdown = schemes_report(result)
    print(markdown)
    update_readme("work_precision_schemes", markdown)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--schemes", action="store_true", help="the time schemes on the lattice (module docstring)")
    parser.add_argument("--quick", action="store_true", help="a few coarse points, no fine references")
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    parser.add_argument("--reuse-reference", action="store_true",
                        help="take the references from results/work_precision.json instead of recomputing them")
    args = parser.parse_args()
    if args.schemes:
        schemes_main(args.report)
        return
    started = time.process_time()
    out = RESULTS / "work_precision.json"
    if args.report:
        stored = json.loads(out.read_text())
        for problem in ("particle", "lattice"):
            stored[f"_{problem}_points"] = [
                Point(problem, d["method"], d["h"], d["dt"], d["options"], d["seconds"], errors=d["errors"])
                for d in stored[problem]["points"]]
            points, keys = stored[f"_{problem}_points"], list(stored[problem]["speedup"]["all errors"]["errors"])
            default = next(i for i, p in enumerate(points) if p.is_default)
            stored[problem]["default_on_front"]["all errors"] = default in pareto_front(points, keys)
        update_readme("work_precision", report(stored))
        out.write_text(json.dumps({k: v for k, v in stored.items() if not k.startswith("_")}, indent=1) + "\n")
        return
    previous = json.loads(out.read_text()) if args.reuse_reference and out.exists() else None
    result: dict = {}
    panels = []
    for problem, keys, points, make_reference, error in (
        ("particle", ["area", "field"], particle_points(args.quick), particle_reference, particle_errors),
        ("lattice", ["elongation", "period"], lattice_points(args.quick), lattice_reference, lattice_errors),
    ):
        if args.quick:  # the reference is the finest point of the quick sweep
            points = [run(p) for p in points]
            failed = [p for p in points if p.failure]
            points = [p for p in points if not p.failure]
            finest = min(points, key=lambda p: (p.h, p.dt))
            reference = {**finest.result, "seconds": 0.0}
        else:
            stored = previous[problem]["reference"] if previous else None
            # a stored lattice reference of another time window is not reusable
            if stored is not None and problem == "lattice" and not np.isclose(stored["times"][-1], RELAX + SHEAR):
                stored = None
            reference = stored if stored is not None else make_reference()
            points = [run(p) for p in points]
            failed = [p for p in points if p.failure]
            points = [p for p in points if not p.failure]
        for p in points:
            p.errors = error(p, reference)
        fronts = {key: pareto_front(points, [key]) for key in keys} | {"all errors": pareto_front(points, keys)}
        default_index = next(i for i, p in enumerate(points) if p.is_default)
        result[problem] = {
            "reference": reference, "reference_seconds": reference["seconds"],
            "points": [{"label": p.label, "method": p.method, "h": p.h, "dt": p.dt, "options": p.options,
                        "seconds": p.seconds, "errors": p.errors, "default": p.is_default, "command": p.command(),
                        "on_front": {k: i in fronts[k] for k in keys}} for i, p in enumerate(points)],
            "failed": [{"label": p.label, "h": p.h, "dt": p.dt, "options": p.options, "message": p.failure,
                        "command": p.command()} for p in failed],
            "default_on_front": {k: default_index in front for k, front in fronts.items()},
            "speedup": ({"all errors": speedup_vs_fd(points, keys)} | {k: speedup_vs_fd(points, [k]) for k in keys}
                        if not args.quick else {}),
        }
        result[f"_{problem}_points"] = points
        panels += [(f"({'a' if problem == 'particle' else 'b'}) {problem}: {k}", points, k) for k in keys]
    if not args.quick:
        result["speedup_vs_fd"] = result["lattice"]["speedup"]["all errors"]["speedup_vs_fd"]
    result["cpu_seconds"] = time.process_time() - started
    RESULTS.mkdir(exist_ok=True)
    serialisable = {k: v for k, v in result.items() if not k.startswith("_")}
    if not args.quick:
        out.write_text(json.dumps(serialisable, indent=1) + "\n")
        plot(panels, RESULTS / "work_precision.png")
        markdown = report(result)
        print(markdown)
        update_readme("work_precision", markdown)
    else:
        for problem in ("particle", "lattice"):
            for p in result[f"_{problem}_points"]:
                print(problem, p.label, p.h, p.dt, f"{p.seconds:.2f}", p.errors)
    print(f"{result['cpu_seconds'] / 60:.1f} CPU-min")


if __name__ == "__main__":
    main()
