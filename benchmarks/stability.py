"""Stability matrix: scenarios × schemes, and the largest safe dt of the default scheme.

    python benchmarks/stability.py [--quick]     # the matrix and the accuracy sweep (~5 CPU-min)
    python benchmarks/stability.py --merged 8 [--quick]   # the default in calls of 8 steps, against stability.json
    python benchmarks/stability.py --long        # the paper's scene over 1.02e5 time units (~20 min)
    python benchmarks/stability.py --long --precision double   # the same in double (results/stability_long_double.json)

Schemes: ``fem-adaptive`` (the default: error-controlled second-order substeps, dt = the
largest), ``fem-sav2`` (second order at fixed dt), ``fem-euler`` (first order, lumped mass,
stabilisation "auto"), ``fem-consistent`` (first order,
consistent mass, "auto"), ``fem-S0`` (first order, lumped, stabilisation 0) and ``fd`` (the
paper's explicit Heun scheme, :mod:`femphase.timestepping.fd`; its constructor refuses a dt above its
stability limit, which is recorded as outcome "rejected"). The accuracy sweep
(``fem-default``) runs the scene defaults.

Scenes are small where the question allows: the "slab" is the paper's density in a
70 × 24 channel (hexagonal N = 10, 2 rows touching the walls, initial discs of R/2), sheared
with the paper's velocity *gradient* γ̇/240 (u = γ̇ y/240, as in the paper's 70 × 240
channel), so γ̇ means the same as in the paper. Every case starts from its scene's initial
discs, so the large-dt steps meet the full relaxation transient.

Per case: ``stable`` (ran to the end), ``energy_monotone`` (no-flow cases: the discrete free
energy never rises by more than 1e-10 relative between steps; null with flow),
``max_overshoot`` (largest excursion of any φ outside [0, 1] over the run), ``silent_nan``
(a non-finite value in the state without a BlowUpError: must be false), ``message`` (the
error), ``area_drift`` (max over particles of |A_i(T) − A_i(T/2)| / πR_i², A = ∫φ²: the
change over the second half of the run, after the initial transient).

``--long`` writes results/stability_long.json (read into stability.json by the next plain
run): the lattice scene at h = 1, dt = 1, default numerics, relaxed 2000 and sheared at
γ̇ = 0.1487 for 1e5 time units, the areas every 500 time units.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.analysis.shape import shape_observables
from femphase.model.energy import WindowedFields
from femphase.errors import BlowUpError, SceneError
from femphase.timestepping.fd import explicit_stability_limit
from femphase.scene import Phase, scene_from_dict
from femphase.run.simulation import Simulation, Tracker

from common import markdown_table, update_readme

RESULTS = Path(__file__).parent / "results"
PAPER_LY = 240.0  # the paper's channel width: γ̇/240 is its velocity gradient
SCHEMES = {
    "fem-adaptive": {"scheme": "adaptive"},
    "fem-sav2": {"scheme": "sav2"},
    "fem-euler": {"scheme": "euler"},
    "fem-consistent": {"scheme": "euler", "mass": "consistent"},
    "fem-S0": {"scheme": "euler", "stabilisation": 0.0},
    "fd": {},
}
ENERGY_TOLERANCE = 1e-10  # relative rise of F between steps still counted as monotone
ACCURACY_TOLERANCE = 0.05  # "accurate enough": elongation within 5 % of the dt = 0.1 run


def shear_flow(rate: float) -> dict:
    """The paper's shear γ̇ (velocity gradient γ̇/240) in a channel of any width."""
    if rate == 0:
        return {"type": "none"}
    return {"type": "shear", "rate": rate / PAPER_LY, "scale": "shear_rate"}


SLAB = {"domain": {"Lx": 70.0, "Ly": 24.0, "h": 1.0}, "particles": {"layout": "hexagonal", "N": 10}}


def scenarios(quick: bool) -> list[dict]:
    """(name, scene tables, γ̇ values, FEM dt values, duration rule) of every scenario."""
    rates = (0.0, 1.0) if quick else (0.0, 0.1, 1.0, 10.0)
    steps = (0.1, 1.0, 10.0, 100.0)
    extra = (1.0, 10.0)
    out = [{"name": "slab", "scene": SLAB, "rates": rates, "dts": steps}]
    if quick:
        return out
    return out + [
        {"name": "slab mu x10", "scene": {**SLAB, "model": {"mu": 200.0}}, "rates": (0.0, 1.0), "dts": extra},
        # the same with the blow-up guard widened: μ = 200 pushes φ to ≈ 1.9 in the transient
        {"name": "slab mu x10, blowup_margin 5", "scene": {**SLAB, "model": {"mu": 200.0}}, "rates": (0.0,),
         "dts": extra, "numerics": {"blowup_margin": 5.0}},
        {"name": "slab kappa x10", "scene": {**SLAB, "model": {"kappa": 5.0}}, "rates": (0.0, 1.0), "dts": extra},
        {"name": "slab lambda/h = 1 (h = 2)", "scene": {**SLAB, "domain": {"Lx": 70.0, "Ly": 24.0, "h": 2.0}},
         "rates": (0.0, 1.0), "dts": extra},
        {"name": "pressed against a wall", "rates": (0.0, 1.0), "dts": extra, "scene": {
            "domain": SLAB["domain"],
            # discs of the full radius R = 8 centred 4 from the wall, 14 apart: they overlap
            # each other and are cut by the wall
            "particles": {"layout": "list", "centres": [[7.0 + 14.0 * k, 4.0] for k in range(5)],
                          "initial_radius": 8.0}}},
        {"name": "overlapping initial fields", "rates": (0.0,), "dts": (1.0, 10.0, 100.0), "scene": {
            "domain": SLAB["domain"],
            "particles": {"layout": "list", "centres": [[35.0, 12.0], [37.0, 12.0], [35.0, 14.0]],
                          "initial_radius": 8.0}}},
        {"name": "dense random N = 100", "rates": (0.0, 1.0), "dts": extra, "duration": 300.0, "fd_duration": 50.0,
         "scene": {"domain": {"Lx": 70.0, "Ly": 240.0, "h": 1.0}, "particles": {"layout": "random", "N": 100}}},
    ]


def build_scene(tables: dict, numerics: dict, dt: float, duration: float, flow: dict):
    return scene_from_dict({
        "name": "stability", **tables, "numerics": numerics, "output": {"fields": False},
        "phases": [{"name": "run", "duration": duration, "dt": dt, "frame_interval": duration, "flow": flow}],
    })


def fd_time_step(scene) -> float:
    """The paper's dt = 0.1, or the largest of 0.05, 0.02, 0.01 the FD scheme accepts."""
    flow = scene.phases[0].flow
    speed = flow.get("rate", 0.0) * scene.domain.width if flow["type"] == "shear" else 0.0
    limit = explicit_stability_limit(scene.model, scene.domain.spacing, speed, float(np.min(scene.radii)))
    return next((dt for dt in (0.1, 0.05, 0.02, 0.01) if dt <= limit), 0.01)


def run_case(scenario: str, scheme: str, tables: dict, rate: float, dt: float, duration: float,
             numerics: dict | None = None, steps_per_call: int = 1) -> dict:
    """Run one case in calls of ``steps_per_call`` steps (``Stepper.step``), watching energy,
    bounds and finiteness after each call."""
    flow = shear_flow(rate)
    method = "fd" if scheme == "fd" else "fem"
    record = {"scenario": scenario, "scheme": scheme, "gamma_dot": rate, "dt": dt, "duration": duration,
              "stable": False, "outcome": "ran", "energy_monotone": None, "max_energy_rise": None,
              "max_overshoot": 0.0, "silent_nan": False, "message": "", "area_drift": None,
              "min_area_ratio": None, "stabilisation": None, "steps": 0, "seconds": 0.0}
    scene = build_scene(tables, {**SCHEMES[scheme], **(numerics or {})}, dt, duration, flow)
    simulation = Simulation(scene, method)
    state = scene.initial_state()
    phase: Phase = scene.phases[0]
    target = np.pi * state.radii**2
    try:
        stepper = simulation.stepper(phase, state.radii)
    except SceneError as exc:
        record.update(outcome="rejected", message=str(exc))
        return record
    record["stabilisation"] = getattr(stepper.scheme, "stabilisation", None)  # the FD scheme has none
    still = flow["type"] == "none"

    def free_energy() -> float:
        """The discrete free energy of the state (the stepper's terms, the paper's)."""
        layout, phi = state.flat()
        fields = WindowedFields(phi, layout, state.radii, simulation.domain.stiffness_apply(layout))
        return stepper.energy.parts(fields).total

    energies = [free_energy()] if still else []
    half_area = None
    started = time.process_time()
    try:
        half = phase.n_steps // 2  # calls end there too: the area drift's first sample
        while state.step < phase.n_steps:
            end = half if state.step < half else phase.n_steps
            stepper.step(state, min(steps_per_call, end - state.step))
            values = np.concatenate([f.ravel() for f in state.fields])
            if not np.all(np.isfinite(values)):
                record["silent_nan"] = True
                raise RuntimeError(f"non-finite φ after step {state.step} without a BlowUpError")
            record["max_overshoot"] = max(record["max_overshoot"], float(-values.min()), float(values.max() - 1))
            if still:
                energies.append(free_energy())
            if state.step == half:
                half_area = shape_observables(state).area
        record["stable"] = True
    except BlowUpError as exc:
        record.update(outcome="blew up", message=str(exc))
    except Exception as exc:  # anything else is a bug to report, with its type
        record.update(outcome="error", message=f"{type(exc).__name__}: {exc}")
    record["seconds"] = time.process_time() - started
    record["steps"] = state.step
    if energies and len(energies) > 1:
        rises = np.diff(energies) / np.abs(energies[:-1])
        record["max_energy_rise"] = float(rises.max())
        record["energy_monotone"] = bool(rises.max() <= ENERGY_TOLERANCE)
    if record["stable"]:
        area = shape_observables(state).area
        reference = area if half_area is None else half_area
        record["area_drift"] = float(np.max(np.abs(area - reference) / target))
        record["min_area_ratio"] = float(np.min(area / target))
    return record


def stability_matrix(quick: bool, schemes=tuple(SCHEMES), steps_per_call: int = 1) -> list[dict]:
    cases = []
    for spec in scenarios(quick):
        for rate in spec["rates"]:
            runs = [(scheme, dt) for dt in spec["dts"] for scheme in schemes]
            fd_dt = fd_time_step(build_scene(spec["scene"], {}, 1.0, 1.0, shear_flow(rate)))
            if fd_dt not in spec["dts"] and "fd" in schemes:
                runs.append(("fd", fd_dt))
            for scheme, dt in runs:
                base = spec.get("fd_duration" if scheme == "fd" else "duration", 200.0)
                duration = max(base, 20 * dt)
                if scheme == "fd" and dt < 0.1:
                    duration = min(duration, 100.0)  # the FD's cost ∝ 1/dt
                case = run_case(spec["name"], scheme, spec["scene"], rate, dt, duration, spec.get("numerics"),
                                steps_per_call)
                cases.append(case)
                print(f"{case['scenario']:<28} γ̇={rate:<5g} {scheme:<15} dt={dt:<6g} {case['outcome']:<8} "
                      f"overshoot={case['max_overshoot']:.2e} monotone={case['energy_monotone']} "
                      f"{case['seconds']:.1f}s {case['message'][:80]}", flush=True)
    return cases


# -- accuracy of large steps: an isolated particle in shear -----------------------------------------
def sheared_particle(rate: float, dt: float, relax: float = 100.0, shear: float = 1200.0, every: float = 20.0) -> dict:
    """Elongation r(t) of one particle (R = 8, started at R) in the paper's 70 × 240 channel,
    relaxed then sheared at γ̇; sampled every ``every`` time units of the shear phase."""
    tables = {"domain": {"Lx": 70.0, "Ly": 240.0, "h": 1.0},
              "particles": {"layout": "single", "initial_radius": 8.0}}
    scene = scene_from_dict({
        "name": "accuracy", **tables, "output": {"fields": False},
        "phases": [{"name": "relax", "duration": relax, "dt": dt, "frame_interval": relax},
                   {"name": "shear", "duration": shear, "dt": dt, "frame_interval": every,
                    "flow": {"type": "shear", "rate": rate}}],
    })
    recorder = ShapeRecorder()
    started = time.process_time()
    record = {"scenario": f"single particle, shear γ̇={rate:g} (accuracy)", "scheme": "fem-default",
              "gamma_dot": rate, "dt": dt, "duration": relax + shear, "energy_monotone": None,
              "silent_nan": False, "message": "", "outcome": "ran"}
    try:
        Simulation(scene).run(scene.initial_state(), [recorder])
        record["stable"] = True
    except BlowUpError as exc:
        record.update(stable=False, outcome="blew up", message=str(exc))
    record["seconds"] = time.process_time() - started
    times, r, area = recorder.arrays()
    shear_frames = times >= relax - 1e-9
    record.update(times=times[shear_frames].tolist(), elongation=r[shear_frames].tolist(),
                  max_overshoot=recorder.max_overshoot,
                  area_drift=float(abs(area[-1] - area[-len(area) // 2]) / (np.pi * 64.0)))
    return record


class ShapeRecorder(Tracker):
    """Times, elongation and area of particle 0, and the largest excursion out of [0, 1], at frames."""

    needs = frozenset({"shape"})

    def __init__(self) -> None:
        self.rows: list[tuple[float, float, float]] = []
        self.max_overshoot = 0.0

    def frame(self, frame) -> None:
        self.rows.append((frame.state.time, float(frame.shape.elongation[0]), float(frame.shape.area[0])))
        values = np.concatenate([f.ravel() for f in frame.state.fields])
        self.max_overshoot = max(self.max_overshoot, float(-values.min()), float(values.max() - 1))

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return tuple(np.array(column) for column in zip(*self.rows))


def accuracy_sweep(quick: bool) -> list[dict]:
    """Elongation error against the dt = 0.1 run: max_t |r − r_ref| / max_t r_ref over the
    shear phase (compared at common times) and the error of the final value."""
    dts = (0.1, 1.0, 10.0) if quick else (0.1, 0.5, 1.0, 2.0, 4.0, 10.0, 20.0)  # all divide 20
    cases = []
    for rate in (1.0, 0.1487):
        runs = [sheared_particle(rate, dt) for dt in dts]
        reference = runs[0]
        ref_t, ref_r = np.array(reference["times"]), np.array(reference["elongation"])
        for run in runs:
            t, r = np.array(run["times"]), np.array(run["elongation"])
            common_t = np.isin(np.round(ref_t, 6), np.round(t, 6))
            if run["stable"] and common_t.any():
                mine = np.interp(ref_t[common_t], t, r)
                run["elongation_error"] = float(np.max(np.abs(mine - ref_r[common_t])) / np.max(ref_r))
                run["final_elongation_error"] = float(abs(r[-1] - ref_r[-1]) / ref_r[-1])
                run["final_elongation"] = float(r[-1])
            run["accurate"] = bool(run["stable"] and run.get("elongation_error", 1.0) <= ACCURACY_TOLERANCE)
            del run["times"], run["elongation"]
            cases.append(run)
            print(f"accuracy γ̇={rate:<7g} dt={run['dt']:<5g} r_final={run.get('final_elongation', float('nan')):.4f} "
                  f"error={run.get('elongation_error', float('nan')):.2e} {run['seconds']:.1f}s", flush=True)
    return cases


def largest_safe_dt(cases: list[dict]) -> float:
    """The largest dt at which every accuracy case is accurate, and every smaller one too."""
    by_dt: dict[float, bool] = {}
    for case in cases:
        if case["scenario"].endswith("(accuracy)"):
            by_dt[case["dt"]] = by_dt.get(case["dt"], True) and case["accurate"]
    safe = 0.0
    for dt in sorted(by_dt):
        if not by_dt[dt]:
            break
        safe = dt
    return safe


# -- the paper's protocol: area drift over 1e5 time units ------------------------------------------
class AreaLog(Tracker):
    """Areas and mean elongation at every frame, written to ``path`` as the run goes."""

    needs = frozenset({"shape"})

    def __init__(self, path: Path, relax: float, scheme: str = "fem-default") -> None:
        self.path, self.relax, self.scheme = path, relax, scheme
        self.times: list[float] = []
        self.areas: list[list[float]] = []
        self.elongation: list[float] = []
        self.max_overshoot = 0.0
        self.started = time.process_time()

    def frame(self, frame) -> None:
        self.times.append(frame.state.time)
        self.areas.append(frame.shape.area.tolist())
        self.elongation.append(float(np.mean(frame.shape.elongation)))
        values = np.concatenate([f.ravel() for f in frame.state.fields])
        self.max_overshoot = max(self.max_overshoot, float(-values.min()), float(values.max() - 1))
        self.write("running")

    def finish(self, state, error) -> None:
        self.write("completed" if error is None else f"failed: {error}")

    def write(self, status: str) -> None:
        self.path.write_text(json.dumps(long_run_case(self, status), indent=1) + "\n")


def long_run_case(log: AreaLog, status: str) -> dict:
    times, areas = np.array(log.times), np.array(log.areas)
    target = np.pi * 8.0**2
    shearing = times >= log.relax - 1e-9
    record = {"scenario": "paper lattice N = 100, 1e5 time units of shear", "scheme": log.scheme,
              "gamma_dot": 0.1487, "dt": 1.0, "duration": float(times[-1]), "status": status,
              "stable": status == "completed", "energy_monotone": None, "silent_nan": False,
              "message": "" if status in ("completed", "running") else status,
              "cpu_seconds": time.process_time() - log.started,
              "times": times.tolist(), "mean_area_ratio": (areas.mean(axis=1) / target).tolist(),
              "mean_elongation": log.elongation}
    if shearing.sum() >= 2:
        sheared = areas[shearing] / target
        mean = sheared.mean(axis=1)
        slope = np.polyfit(times[shearing], mean, 1)[0]
        record.update(
            # the largest change of any particle's area since the shear started
            area_drift=float(np.max(np.abs(sheared - sheared[0]))),
            mean_area_change=float(mean[-1] - mean[0]),
            mean_area_trend_per_1e5=float(slope * 1e5),
        )
    record["max_overshoot"] = log.max_overshoot  # sampled at the frames only
    return record


def long_run(path: Path, shear: float = 1e5, relax: float = 2000.0, precision: str | None = None) -> None:
    """The long run at the default numerics, or with ``numerics.precision`` = ``precision``."""
    scene = scene_from_dict({
        "name": "paper lattice, long", "domain": {"Lx": 70.0, "Ly": 240.0, "h": 1.0},
        "particles": {"layout": "hexagonal", "N": 100}, "output": {"fields": False},
        "numerics": {} if precision is None else {"precision": precision},
        "phases": [{"name": "relax", "duration": relax, "dt": 1.0, "frame_interval": 500.0},
                   {"name": "shear", "duration": shear, "dt": 1.0, "frame_interval": 500.0,
                    "flow": {"type": "shear", "rate": 0.1487}}],
    })
    scheme = "fem-default" if precision is None else f"fem-default, precision {precision}"
    Simulation(scene).run(scene.initial_state(), [AreaLog(path, relax, scheme)])


# -- report ------------------------------------------------------------------------------------------
def report(cases: list[dict], safe_dt: float) -> str:
    def fmt(value, spec=".1e"):
        if value is None:
            return "–"
        if isinstance(value, bool):
            return "yes" if value else "**no**"
        return format(value, spec)

    matrix = [c for c in cases if not c["scenario"].endswith("(accuracy)") and "status" not in c]
    rejected = [c for c in matrix if c["outcome"] == "rejected"]
    matrix = [c for c in matrix if c["outcome"] != "rejected"]
    rows = [[c["scenario"], fmt(c["gamma_dot"], "g"), c["scheme"], fmt(c["dt"], "g"),
             c["outcome"] + ("" if c["outcome"] != "blew up" else f" (step {c['message'].split('step ')[1].split(' ')[0]})"),
             fmt(c["energy_monotone"]), fmt(c["max_overshoot"], ".1e"),
             "**YES**" if c["silent_nan"] else "no", fmt(c["area_drift"], ".1e"),
             fmt(c.get("stabilisation"), ".2g")] for c in matrix]
    text = [markdown_table(["scenario", "γ̇", "scheme", "dt", "outcome", "energy monotone",
                            "max overshoot", "silent NaN", "area drift", "S"], rows)]
    if rejected:
        text.append(f"\nNot in the table: {len(rejected)} FD cases at dt ≥ {min(c['dt'] for c in rejected):g}, all "
                    f"refused by the FD constructor before any step (SceneError), e.g. “{rejected[0]['message']}”.")
    accuracy = [c for c in cases if c["scenario"].endswith("(accuracy)")]
    if accuracy:
        text.append("\nAccuracy of large steps (fem-default; one particle R = 8 in the paper's channel, "
                    "relaxed 100, sheared 1200 time units; error = max_t |r − r_ref| / max r_ref against dt = 0.1):\n")
        text.append(markdown_table(
            ["γ̇", "dt", "final r", "r(t) error", "final r error", "accurate (≤ 5 %)"],
            [[fmt(c["gamma_dot"], "g"), fmt(c["dt"], "g"), fmt(c.get("final_elongation"), ".4f"),
              fmt(c.get("elongation_error"), ".1e"), fmt(c.get("final_elongation_error"), ".1e"),
              fmt(c["accurate"])] for c in accuracy]))
        text.append(f"\n**Largest safe dt of the default scheme: {safe_dt:g}** (every accuracy case within "
                    f"{ACCURACY_TOLERANCE:.0%} at this and every smaller dt tried).")
    long = [c for c in cases if "status" in c]
    for c in long:
        text.append(f"\nPaper lattice (N = 100, h = 1, dt = 1, defaults), relaxed 2000 then sheared at γ̇ = 0.1487 "
                    f"until t = {c['duration']:g} ({c['status']}): largest change of any particle's area since the "
                    f"shear started {fmt(c.get('area_drift'), '.2e')} πR²; mean area {fmt(c.get('mean_area_change'), '.2e')} πR² "
                    f"(linear trend {fmt(c.get('mean_area_trend_per_1e5'), '.2e')} πR² per 1e5 time units); "
                    f"{c['cpu_seconds'] / 60:.0f} CPU-min.")
    return "\n".join(text)


def merged_matrix(quick: bool, steps_per_call: int) -> None:
    """The default scheme's cases of the matrix in calls of several steps, against its
    step-by-step cases of the last full run (results/stability.json)."""
    merged = stability_matrix(quick, ("fem-adaptive",), steps_per_call)
    single = {(c["scenario"], c["gamma_dot"], c["dt"]): c for c in json.loads((RESULTS / "stability.json").read_text())
              if c.get("scheme") == "fem-adaptive"}
    rows = []
    for case in merged:
        before = single.get((case["scenario"], case["gamma_dot"], case["dt"]))
        rows.append({"case": f"{case['scenario']} | γ̇ {case['gamma_dot']:g} | dt {case['dt']:g}",
                     "outcome": [before["outcome"] if before else None, case["outcome"]],
                     "area_drift": [before["area_drift"] if before else None, case["area_drift"]],
                     "max_overshoot": [before["max_overshoot"] if before else None, case["max_overshoot"]],
                     "energy_monotone": [before["energy_monotone"] if before else None, case["energy_monotone"]]})
    same = sum(r["outcome"][0] == r["outcome"][1] for r in rows)
    (RESULTS / "stability_merged.json").write_text(json.dumps({
        "command": f"python benchmarks/stability.py --merged {steps_per_call}" + (" --quick" if quick else ""),
        "steps_per_call": steps_per_call, "same_outcome": same, "cases": len(rows), "rows": rows}, indent=1) + "\n")
    print(f"calls of {steps_per_call}: {same} of {len(rows)} cases end as step by step")
    for r in rows:
        print(f"{r['case']:<55} outcome {r['outcome']} area drift {r['area_drift']} monotone {r['energy_monotone']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="the slab at γ̇ = 0, 1 and a coarse dt sweep only")
    parser.add_argument("--long", action="store_true", help="only the 1e5 time-unit run (results/stability_long.json)")
    parser.add_argument("--precision", choices=["mixed", "double"],
                        help="with --long: this numerics.precision, written to results/stability_long_PRECISION.json "
                             "(not merged into stability.json)")
    parser.add_argument("--report", action="store_true",
                        help="no runs: merge the latest stability_long.json into stability.json, rewrite the README section")
    parser.add_argument("--merged", type=int, metavar="K",
                        help="only the default scheme's cases, in calls of K steps (numerics.merged_steps), "
                             "compared with its step-by-step cases in stability.json (results/stability_merged.json)")
    args = parser.parse_args()
    RESULTS.mkdir(exist_ok=True)
    if args.merged:
        merged_matrix(args.quick, args.merged)
        return
    long_path = RESULTS / "stability_long.json"
    if args.long:
        if args.precision is None:
            long_run(long_path)
        else:
            long_run(RESULTS / f"stability_long_{args.precision}.json", precision=args.precision)
        return
    started = time.process_time()
    if args.report:
        cases = [c for c in json.loads((RESULTS / "stability.json").read_text()) if "status" not in c]
    else:
        cases = stability_matrix(args.quick)
        (RESULTS / "stability.json").write_text(json.dumps(cases, indent=1) + "\n")  # kept if the sweep fails
        cases += accuracy_sweep(args.quick)
    if long_path.exists():
        cases.append(json.loads(long_path.read_text()))
    safe_dt = largest_safe_dt(cases)
    (RESULTS / "stability.json").write_text(json.dumps(cases, indent=1) + "\n")
    markdown = report(cases, safe_dt)
    print(markdown)
    if not args.quick:
        update_readme("stability", markdown)
    print(f"silent NaN anywhere: {any(c['silent_nan'] for c in cases)}; "
          f"largest safe dt: {safe_dt:g}; {(time.process_time() - started) / 60:.1f} CPU-min")


if __name__ == "__main__":
    main()
