"""Does the adaptive scheme's tolerance control its error? Tolerance proportionality.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/tolerance.py [--cases disc pair collision lattice] [--estimate doubling]

For each ``numerics.tolerance_t`` (default scheme otherwise, dt = 10), the global error in
time against a reference converged in time at the same h = 1 (the fixed-step second-order
scheme sav2 at a small dt, computed once per case and cached in results/), and the CPU
seconds of the run (process clock):

* ``disc``: one disc relaxing from R/2 in a 40 × 40 channel, no flow; error: the largest
  |area − reference| at t = 10, 20, 50, 100 (lattice units²); reference sav2 at dt = 0.05;
* ``pair``: two discs of R = 8 with centres 20 apart across a 27 × 120 channel, no flow,
  20000 time units; error: |d(t) − reference| at the last frame, d the centroid separation
  (lattice units); reference sav2 at dt = 0.25 and 0.125, extrapolated (Richardson, order 2),
  with the observed order from dt = 0.5, 0.25, 0.125 beside it;
* ``collision``: two discs of R = 8 passing each other in a shear (60 × 40 channel, u = γ̇ y/Ly
  at γ̇ = 1, the repulsion κ ten times the paper's, the upper disc 20 behind, centres 8 apart
  across the flow), 200 time units from t = 0 with no relaxation, on the whole channel
  (``numerics.windows = false``: the window refits' cuts do not converge in time, and sav2's
  references over dt = 0.025, 0.0125, 0.00625 diverged at order −4.6 with windows, converged at
  2.0 without); error: the largest |E_rep(t) − reference| over t = 10, 20, …, 200 relative to
  the largest reference E_rep, the repulsion energy, in which the split decay's error shows
  (the separation across the flow, which the collision widens from 8 to about 12.6, beside
  it); reference sav2 at dt = 0.0125 and 0.00625 in double precision, extrapolated, with the
  observed order from dt = 0.025 beside it. The embedded estimate does not contain the split
  decay's error;
* ``lattice``: the paper's N = 100 hexagonal lattice sheared at γ̇ = 0.1487 over one period
  (benchmarks/work_precision.py's scene and measures): the largest relative error of the
  bulk-mean r(t) and the relative period error; reference sav2 at dt = 0.125 and 0.0625 in
  double precision, extrapolated, with the observed order of r̄(t) from dt = 0.25, 0.125,
  0.0625 beside it (``observed_order``; 2 justifies the extrapolation: see
  docs/decisions/0018-nyquist-mode.md for a case where it was 1.4).

The tightest tolerances' errors (1e-5 relative on the lattice, 2e-7 on the pair) are below
a single sav2 run's at the smallest dt affordable, hence the extrapolated references; their
own error (``own_error`` in the JSON, |fine − coarse|/3) is reported beside them.

Each case runs over its own three decades (WINDOWS), those over which its substep is set by
the error estimate, and at the default tolerance. A tolerance that controls the error gives
a log–log slope of error against tolerance near 1 over the window (proportionality); a
slope near 0 means something else sets the step. The disc and the pair run without flow,
where the scheme allows 0.01·(tolerance_t/0.1)^(3/4) per substep, a tenth of it at the
default (:meth:`femphase.config.Numerics.substep_tolerance`,
docs/decisions/0044-still-tolerance-power.md); the lattice's shear allows the tolerance itself,
and below the default its substeps decay on both sides of their midpoint steps instead of
merging their half-decays across the advection, a first-order error
(docs/decisions/0046-decays-split-below-the-default.md). The pair's window starts at 1e-4: from 1e-3
up its estimate at the substep 3.33 is below the tolerance (the area-mode ceiling caps the
substeps the controller would grow), so every looser tolerance runs about the same
substeps and gives about the same error (1.4e-3). The lattice's starts at 1e-2: at 0.1
its substep is 3.33 throughout the shear, its estimate ≈ 0.37 of the tolerance, inside the
band where the controller keeps a size (docs/design/time-schemes.md); the ceiling caps
none of those substeps (docs/decisions/0036-ceiling-idle-under-flow.md).

Why a slope is what it is: the mean accepted substep h̄ of the measured phase (the disc's and
the pair's relaxation, the lattice's shear) follows the tolerance as tol^α, and the error
follows h̄ as h̄^p, so the slope is α·p. The embedded estimate is a first-order step's local
error, O(h²), so α ≈ 1/2 wherever the estimate sets the step; p is the observable's own
order in the substep, which need not be the scheme's formal 2 (``substep_slope`` α and
``order_in_substep`` p in the JSON).

``--estimate doubling`` runs the cases with flow (``collision``, ``lattice``) with the
step-doubling estimate (``numerics.estimate``), which contains every error of the step and
which ``tolerance_t`` bounds per time unit, over the tolerances of DOUBLING_WINDOWS, and
writes results/tolerance_doubling.json and its own README section.

Also reported: the spatial error at h = 1, against which the default's time error is
judged (the default must stay below it, ``numerics.tolerance_t`` in docs/scenes.md): the
difference between h = 0.5 and h = 1 (a lower bound of the h = 1 error at second order,
3/4 of it), at every compared time for the disc, at t = 20000 for the pair, and for the
lattice r(t)'s largest relative difference (h = 0.5 by the adaptive scheme at 1e-3, whose
time error is below 0.1 %). Writes results/tolerance.json; ``--report`` rewrites the
README section from it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np

from femphase.analysis.periods import first_peaks
from femphase.config import Numerics
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict

HERE = Path(__file__).resolve().parent
RESULT = HERE / "results" / "tolerance.json"
RESULT_DOUBLING = HERE / "results" / "tolerance_doubling.json"
REFERENCES = HERE / "results" / "tolerance_references.json"
DISC_TIMES = (10.0, 20.0, 50.0, 100.0)
#: Three decades of tolerance per case over which its substep is set by the error estimate
#: (module docstring)
WINDOWS = {"disc": (0.5, 5e-2, 5e-3, 5e-4), "pair": (1e-4, 1e-5, 1e-6, 1e-7), "collision": (1e-2, 1e-3, 1e-4, 1e-5),
           "lattice": (1e-2, 1e-3, 1e-4, 1e-5)}
#: The same with the step-doubling estimate, whose tolerance is per time unit (the lattice's
#: substeps average 1.7 at 1e-3 and 0.58 at 1e-4)
DOUBLING_WINDOWS = {"collision": (1e-4, 1e-5, 1e-6, 1e-7), "lattice": (1e-3, 1e-4, 1e-5, 1e-6)}
FLOW_CASES = ("collision", "lattice")
DEFAULT = Numerics().tolerance_t


def disc_scene(numerics: dict, dt: float, h: float = 1.0):
    return scene_from_dict({
        "name": "disc from R/2", "domain": {"Lx": 40.0, "Ly": 40.0, "h": h},
        "particles": {"layout": "single", "initial_radius": 4.0}, "numerics": numerics,
        "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "relax", "duration": 100.0, "dt": dt, "frame_interval": 10.0}]})


def pair_scene(numerics: dict, dt: float, h: float = 1.0):
    return scene_from_dict({
        "name": "pair", "domain": {"Lx": 27.0, "Ly": 120.0, "h": h},
        "particles": {"layout": "list", "centres": [[13.5, 50.0], [13.5, 70.0]], "initial_radius": 8.0},
        "numerics": numerics, "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "relax", "duration": 20000.0, "dt": dt, "frame_interval": 1000.0}]})


def collision_scene(numerics: dict, dt: float, h: float = 1.0):
    return scene_from_dict({
        "name": "collision", "domain": {"Lx": 60.0, "Ly": 40.0, "h": h}, "model": {"kappa": 5.0},
        "particles": {"layout": "list", "centres": [[34.0, 16.0], [14.0, 24.0]], "initial_radius": 8.0},
        "numerics": {**numerics, "windows": False}, "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "shear", "duration": 200.0, "dt": dt, "frame_interval": 10.0,
                    "flow": {"type": "shear", "rate": 1.0}}]})


def simulate(scene) -> tuple[FrameRecorder, float, dict]:
    """(frames, CPU seconds, :func:`common.phase_substeps` of its last phase)."""
    recorder = FrameRecorder()
    state = scene.initial_state()
    started = time.process_time()
    Simulation(scene).run(state, [recorder])
    return recorder, time.process_time() - started, common.phase_substeps(state.memory, len(scene.phases) - 1,
                                                                      scene.phases[-1].duration)


def disc_areas(numerics: dict, dt: float, h: float = 1.0) -> tuple[list[float], float, dict]:
    recorder, cpu, counted = simulate(disc_scene(numerics, dt, h))
    area = recorder.series("area")[:, 0]
    return [float(area[np.argmin(np.abs(recorder.times - t))]) for t in DISC_TIMES], cpu, counted


def pair_separation(numerics: dict, dt: float, h: float = 1.0) -> tuple[float, float, dict]:
    recorder, cpu, counted = simulate(pair_scene(numerics, dt, h))
    y = recorder.series("y")
    return float(y[-1, 1] - y[-1, 0]), cpu, counted


def collision_series(numerics: dict, dt: float, h: float = 1.0) -> tuple[dict, float, dict]:
    """({"repulsion": E_rep, "separation": Δy across the flow} at t = 10, 20, …, 200, CPU
    seconds, substeps)."""
    recorder, cpu, counted = simulate(collision_scene(numerics, dt, h))
    y = recorder.series("y")
    return ({"repulsion": recorder.series("repulsion", "global")[1:].tolist(),
             "separation": (y[1:, 1] - y[1:, 0]).tolist()}, cpu, counted)


def collision_errors(series: dict, reference: dict) -> dict:
    """The collision's errors: the repulsion energy's relative to its largest reference value,
    the separation's in lattice units (largest over the frames)."""
    repulsion = np.asarray(reference["repulsion"])
    return {"repulsion": float(np.abs(np.subtract(series["repulsion"], repulsion)).max() / repulsion.max()),
            "separation": float(np.abs(np.subtract(series["separation"], reference["separation"])).max())}


def references(cases: list[str]) -> dict:
    """The time-converged references and the h = 0.5 runs, computed once (minutes) and cached."""
    cached = json.loads(REFERENCES.read_text()) if REFERENCES.exists() else {}
    if "disc" in cases and "disc" not in cached:
        cached["disc"] = {"area": disc_areas({"scheme": "sav2"}, 0.05)[0], "scheme": "sav2", "dt": 0.05,
                          "area_h_0.5": disc_areas({"scheme": "sav2"}, 0.05, h=0.5)[0]}
    if "pair" in cases and "pair" not in cached:
        coarsest, coarse, fine = (pair_separation({"scheme": "sav2"}, dt)[0] for dt in (0.5, 0.25, 0.125))
        cached["pair"] = {"separation": extrapolated(coarse, fine), "own_error": abs(fine - coarse) / 3.0,
                          "observed_order": float(np.log2(abs(coarsest - coarse) / abs(coarse - fine))),
                          "scheme": "sav2", "dt": [0.5, 0.25, 0.125],
                          "separation_h_0.5": pair_separation({"scheme": "sav2"}, 1.0, h=0.5)[0]}
    if "collision" in cases and "collision" not in cached:
        runs = [collision_series(DOUBLE_SAV2, dt)[0] for dt in (0.025, 0.0125, 0.00625)]
        entry = {"scheme": "sav2", "dt": [0.025, 0.0125, 0.00625]}
        for key in ("repulsion", "separation"):
            coarsest, coarse, fine = (np.array(run[key]) for run in runs)
            entry[key] = extrapolated(coarse, fine).tolist()
            entry[f"own_error_{key}"] = float(np.abs(fine - coarse).max() / 3.0)
            entry[f"observed_order_{key}"] = float(np.log2(np.abs(coarsest - coarse).max()
                                                           / np.abs(coarse - fine).max()))
        entry["h_0.5"] = collision_series(DOUBLE_SAV2, 0.0125, h=0.5)[0]
        cached["collision"] = entry
    if "lattice" in cases and "lattice" not in cached:
        cached["lattice"] = lattice_reference()
    REFERENCES.parent.mkdir(exist_ok=True)
    REFERENCES.write_text(json.dumps(cached, indent=1) + "\n")
    return cached


#: The lattice's reference runs: in double precision, because the default mixed precision
#: rounds every flow step's arithmetic to single precision and 57600 steps of 0.0625 add up
#: (the observed order of r̄(t) over dt = 0.25, 0.125, 0.0625 was −1.9 in mixed precision, 1.95
#: in double)
DOUBLE_SAV2 = {"scheme": "sav2", "precision": "double"}


def lattice_reference() -> dict:
    """The lattice's reference (sav2 at dt = 0.125 and 0.0625, extrapolated; the run at 0.25
    gives the observed order that justifies the extrapolation) and its h = 0.5 run."""
    import work_precision as wp

    coarsest, coarse, fine = (wp.run(wp.Point("lattice", "fem", 1.0, dt, DOUBLE_SAV2)).result
                              for dt in (0.25, 0.125, 0.0625))
    series = [np.array(run["mean_elongation"]) for run in (coarsest, coarse, fine)]
    elongation = extrapolated(series[1], series[2]).tolist()
    own = wp.lattice_errors(wp.Point("lattice", "fem", 1.0, 0.0625, result=fine),
                            {"times": fine["times"], "mean_elongation": elongation})
    order = float(np.log2(np.abs(series[0] - series[1]).max() / np.abs(series[1] - series[2]).max()))
    fine_h = wp.run(wp.Point("lattice", "fem", 0.5, 10.0, {"scheme": "adaptive", "tolerance_t": 1e-3})).result
    return {"result": {**fine, "mean_elongation": elongation}, "own_error": own, "observed_order": order,
            "scheme": "sav2", "dt": [0.25, 0.125, 0.0625], "result_h_0.5": fine_h}


def extrapolated(coarse, fine):
    """Richardson's extrapolation of a second-order scheme's results at dt and dt/2, the
    reference. ``own_error`` in the cache is |fine − coarse|/3, the fine run's estimated
    error, which bounds the extrapolated value's in practice."""
    return fine + (fine - coarse) / 3.0


def spatial_errors(case: str, reference: dict) -> dict:
    """The difference between h = 0.5 and h = 1 (module docstring), in the case's error measure."""
    if case == "disc":
        return dict(zip(map(str, DISC_TIMES), np.abs(np.subtract(reference["area_h_0.5"], reference["area"])).tolist()))
    if case == "pair":
        return {"20000.0": abs(reference["separation_h_0.5"] - reference["separation"])}
    if case == "collision":
        return {"repulsion": collision_errors(reference["h_0.5"], reference)["repulsion"]}
    import work_precision as wp

    fine = wp.Point("lattice", "fem", 0.5, 10.0, result=reference["result_h_0.5"])
    return {"elongation": wp.lattice_errors(fine, reference["result"])["elongation"]}


def measure(case: str, tolerance: float, reference: dict, estimate: str = "embedded") -> dict:
    numerics = {"tolerance_t": tolerance, **({} if estimate == "embedded" else {"estimate": estimate})}
    if case == "disc":
        areas, cpu, counted = disc_areas(numerics, 10.0)
        errors = np.abs(np.subtract(areas, reference["area"]))
        return {"error": float(errors.max()), "errors_at": dict(zip(map(str, DISC_TIMES), errors.tolist())),
                "cpu_s": cpu, **counted}
    if case == "pair":
        separation, cpu, counted = pair_separation(numerics, 10.0)
        error = abs(separation - reference["separation"])
        return {"error": error, "errors_at": {"20000.0": error}, "separation": separation, "cpu_s": cpu, **counted}
    if case == "collision":
        series, cpu, counted = collision_series(numerics, 10.0)
        errors = collision_errors(series, reference)
        return {"error": errors["repulsion"], "errors_at": {"repulsion": errors["repulsion"]},
                "separation_error": errors["separation"], "cpu_s": cpu, **counted}
    import work_precision as wp

    # work_precision's points run the first-order scheme unless they name another
    point = wp.run(wp.Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive", **numerics}))
    errors = wp.lattice_errors(point, reference["result"])
    return {"error": errors["elongation"], "errors_at": {"elongation": errors["elongation"]},
            "period_error": errors["period"], "peak_time_errors": peak_time_errors(point.result, reference["result"]),
            "cpu_s": point.seconds, **point.result.get("shear_substeps", {})}


def peak_time_errors(result: dict, reference: dict) -> list[float]:
    """Signed errors (run − reference, time units) of the times of r̄(t)'s first two primary
    peaks under shear, whose difference is the period (work_precision's ``period`` error)."""
    import work_precision as wp

    times = np.array(reference["times"])
    shear = times >= wp.RELAX
    run, ref = (first_peaks(times[shear], np.array(r["mean_elongation"])[shear]) for r in (result, reference))
    return (run - ref).tolist() if len(run) == len(ref) == 2 else [float("nan")] * 2


def slope(tolerances: list[float], errors: list[float]) -> float:
    """Least-squares slope of log error against log tolerance."""
    keep = np.asarray(errors) > 0
    return float(np.polyfit(np.log(np.asarray(tolerances)[keep]), np.log(np.asarray(errors)[keep]), 1)[0])


def below_spatial(row: dict, spatial: dict) -> bool:
    """Whether a run's time error is below the spatial error at every compared time."""
    return all(row["errors_at"][key] < value for key, value in spatial.items())


CASE_NAMES = {"disc": "disc from R/2, no flow (largest area error at t = 10, 20, 50, 100; lattice units²)",
              "pair": "two discs 20 apart, no flow (separation at t = 20000; lattice units)",
              "collision": "two discs colliding in a shear, κ × 10, whole channel (largest repulsion energy "
                           "error / its largest value)",
              "lattice": "lattice sheared at γ̇ = 0.1487 over one period (largest r̄(t) error / max r̄)"}


def report(result: dict) -> str:
    """The README section: per case its window's errors and CPU, the slope, and the default's
    time error against the spatial error at h = 1."""
    def error(case: str, value: float) -> str:
        return f"{100 * value:.2g} %" if case == "lattice" else f"{value:.2g}"

    default_tolerance = result["default"]
    heading = "—" if default_tolerance is None else f"default {default_tolerance:g}: time error"
    lines = [("| case (error measured) | tolerances | error (CPU s) at each | slope | mean substep at each; α, p | "
              f"{heading} | spatial error h = 1 → 0.5 |"), "|---|---|---|---|---|---|---|"]
    for case, entry in result["cases"].items():
        window = [row for row in entry["rows"] if row["tolerance_t"] in entry["window"]]
        default = next((row for row in entry["rows"] if row["tolerance_t"] == default_tolerance), None)
        spatial = entry["spatial_error"]
        judged = None if default is None else "below" if below_spatial(default, spatial) else "**above**"
        lines.append(f"| {CASE_NAMES[case]} | {', '.join(f'{t:g}' for t in entry['window'])} | "
                     + ", ".join(f"{error(case, row['error'])} ({row['cpu_s']:.1f})" for row in window)
                     + f" | {entry['slope']:.2f}"
                     + (f" (period: {entry['period_slope']:.2f})" if "period_slope" in entry else "")
                     + " | " + ", ".join(f"{row['mean_substep']:.3g}" for row in window)
                     + f"; {entry['substep_slope']:.2f}, {entry['order_in_substep']:.2f}"
                     + (" | — | " if default is None else f" | {error(case, default['error'])} ({judged}) | ")
                     + ", ".join(error(case, value) for value in spatial.values()) + " |")
    commands = "; ".join(f"`{entry['command']}`" for entry in result["cases"].values())
    text = "\n".join(lines) + (
        "\n\nα: the log–log slope of the mean accepted substep (the measured phase's duration over its "
        "substeps) against the tolerance; p = slope/α, the order at which the measured error falls with "
        f"that substep. Commands: {commands}.")
    lattice = result["cases"].get("lattice")
    if lattice and all("peak_time_errors" in row for row in lattice["rows"]):
        window = [row for row in lattice["rows"] if row["tolerance_t"] in lattice["window"]]
        text += ("\n\nLattice: signed errors of the first and second peak times of r̄(t) (time units; the "
                 "period is their difference): " + "; ".join(
                     f"{row['tolerance_t']:g}: {row['peak_time_errors'][0]:+.3g}, {row['peak_time_errors'][1]:+.3g}"
                     for row in window) + ".")
    return text


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cases", nargs="+", choices=list(WINDOWS),
                        help="default: every case (with --estimate doubling, those with flow)")
    parser.add_argument("--estimate", choices=["embedded", "doubling"], default="embedded",
                        help="numerics.estimate of the runs (module docstring)")
    parser.add_argument("--output", type=Path, help="default: results/tolerance.json, tolerance_doubling.json")
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    args = parser.parse_args()
    doubling = args.estimate == "doubling"
    windows = DOUBLING_WINDOWS if doubling else WINDOWS
    cases = args.cases or list(windows)
    if set(cases) - set(windows):
        parser.error(f"--estimate doubling runs the cases with flow, {', '.join(FLOW_CASES)}; got {cases}")
    output = args.output or (RESULT_DOUBLING if doubling else RESULT)
    section = "tolerance_doubling" if doubling else "tolerance"
    out = {"cases": {}}
    if output.exists():  # cases measured by an earlier invocation are kept, each with its command
        out["cases"] = json.loads(output.read_text()).get("cases", {})
    if args.report:
        common.update_readme(section, report(json.loads(output.read_text())))
        return
    refs = references(cases)
    simulate(disc_scene({}, 10.0))  # compiles the window kernels, which the first timed run would pay for
    for case in cases:
        tolerances = sorted(set(windows[case]) | (set() if doubling else {DEFAULT}), reverse=True)
        rows = []
        for tolerance in tolerances:
            rows.append({"tolerance_t": tolerance, **measure(case, tolerance, refs[case], args.estimate)})
            print(json.dumps({"case": case, **rows[-1]}), flush=True)
        window = [row for row in rows if row["tolerance_t"] in windows[case]]
        tolerances = [r["tolerance_t"] for r in window]
        error_slope = slope(tolerances, [r["error"] for r in window])
        substep_slope = slope(tolerances, [r["mean_substep"] for r in window])
        # the lattice's period, timed by r̄(t)'s first two peaks
        period = {"period_slope": slope(tolerances, [r["period_error"] for r in window])} if case == "lattice" else {}
        out["cases"][case] = {"rows": rows, "window": list(windows[case]), "slope": error_slope, **period,
                              "substep_slope": substep_slope, "order_in_substep": error_slope / substep_slope,
                              "spatial_error": spatial_errors(case, refs[case]),
                              "reference": {k: v for k, v in refs[case].items()
                                            if not k.startswith("result") and k != "h_0.5"},
                              "command": f"python benchmarks/tolerance.py --cases {case}"
                                         + (" --estimate doubling" if doubling else "")}
        print(f"{case}: log-log slope of error against tolerance {out['cases'][case]['slope']:.2f}", flush=True)
    out["default"] = None if doubling else DEFAULT
    out["estimate"] = args.estimate
    output.parent.mkdir(exist_ok=True)
    output.write_text(json.dumps(out, indent=1) + "\n")
    common.update_readme(section, report(out))


if __name__ == "__main__":
    main()
