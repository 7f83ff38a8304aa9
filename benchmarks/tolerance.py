"""Does the adaptive scheme's tolerance control its error? Tolerance proportionality.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/tolerance.py [--tolerances 0.1 0.01 0.001 0.0001] [--cases disc pair lattice]

For each ``numerics.tolerance_t`` (default scheme otherwise, dt = 10), the global error in
time against a reference converged in time at the same h = 1 (the fixed-step second-order
scheme sav2 at a small dt, computed once per case and cached in results/), and the CPU
seconds of the run (process clock):

* ``disc``: one disc relaxing from R/2 in a 40 × 40 channel, no flow; error: the largest
  |area − reference| at t = 10, 20, 50, 100 (lattice units²); reference sav2 at dt = 0.05;
* ``pair``: two discs of R = 8 with centres 20 apart across a 27 × 120 channel, no flow,
  20000 time units; error: |d(t) − reference| at the last frame, d the centroid separation
  (lattice units); reference sav2 at dt = 0.5;
* ``lattice``: the paper's N = 100 hexagonal lattice sheared at γ̇ = 0.1487 over one period
  (benchmarks/work_precision.py's scene and measures): the largest relative error of the
  bulk-mean r(t) and the relative period error; reference sav2 at dt = 0.25.

A tolerance that controls the error gives a log–log slope of error against tolerance near
1 (proportionality, fitted over the tolerances given); a slope near 0 means something else
(a step ceiling, a splitting error the estimate does not contain) sets the step. Also
reported: the spatial error at h = 1 where the case has one (disc: area at h = 0.5 minus
h = 1, the h-error's lower bound), against which the default's time error is judged.
Writes results/tolerance.json.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict

HERE = Path(__file__).resolve().parent
RESULT = HERE / "results" / "tolerance.json"
REFERENCES = HERE / "results" / "tolerance_references.json"
DISC_TIMES = (10.0, 20.0, 50.0, 100.0)


def disc_scene(numerics: dict, dt: float, h: float = 1.0):
    return scene_from_dict({
        "name": "disc from R/2", "domain": {"Lx": 40.0, "Ly": 40.0, "h": h},
        "particles": {"layout": "single", "initial_radius": 4.0}, "numerics": numerics,
        "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "relax", "duration": 100.0, "dt": dt, "frame_interval": 10.0}]})


def pair_scene(numerics: dict, dt: float):
    return scene_from_dict({
        "name": "pair", "domain": {"Lx": 27.0, "Ly": 120.0, "h": 1.0},
        "particles": {"layout": "list", "centres": [[13.5, 50.0], [13.5, 70.0]], "initial_radius": 8.0},
        "numerics": numerics, "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "relax", "duration": 20000.0, "dt": dt, "frame_interval": 1000.0}]})


def simulate(scene) -> tuple[FrameRecorder, float]:
    recorder = FrameRecorder()
    started = time.process_time()
    Simulation(scene).run(scene.initial_state(), [recorder])
    return recorder, time.process_time() - started


def disc_areas(numerics: dict, dt: float, h: float = 1.0) -> tuple[list[float], float]:
    recorder, cpu = simulate(disc_scene(numerics, dt, h))
    area = recorder.series("area")[:, 0]
    return [float(area[np.argmin(np.abs(recorder.times - t))]) for t in DISC_TIMES], cpu


def pair_separation(numerics: dict, dt: float) -> tuple[float, float]:
    recorder, cpu = simulate(pair_scene(numerics, dt))
    y = recorder.series("y")
    return float(y[-1, 1] - y[-1, 0]), cpu


def references(cases: list[str]) -> dict:
    """The time-converged references, computed once (minutes) and cached."""
    cached = json.loads(REFERENCES.read_text()) if REFERENCES.exists() else {}
    if "disc" in cases and "disc" not in cached:
        cached["disc"] = {"area": disc_areas({"scheme": "sav2"}, 0.05)[0], "scheme": "sav2", "dt": 0.05,
                          "area_h_0.5": disc_areas({"scheme": "sav2"}, 0.05, h=0.5)[0]}
    if "pair" in cases and "pair" not in cached:
        cached["pair"] = {"separation": pair_separation({"scheme": "sav2"}, 0.5)[0], "scheme": "sav2", "dt": 0.5}
    if "lattice" in cases and "lattice" not in cached:
        import work_precision as wp

        point = wp.run(wp.Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"}))
        cached["lattice"] = {"result": point.result, "scheme": "sav2", "dt": 0.25}
    REFERENCES.parent.mkdir(exist_ok=True)
    REFERENCES.write_text(json.dumps(cached, indent=1) + "\n")
    return cached


def measure(case: str, tolerance: float, reference: dict) -> dict:
    numerics = {"tolerance_t": tolerance}
    if case == "disc":
        areas, cpu = disc_areas(numerics, 10.0)
        errors = np.abs(np.subtract(areas, reference["area"]))
        return {"error": float(errors.max()), "errors_at": dict(zip(map(str, DISC_TIMES), errors.tolist())), "cpu_s": cpu}
    if case == "pair":
        separation, cpu = pair_separation(numerics, 10.0)
        return {"error": abs(separation - reference["separation"]), "separation": separation, "cpu_s": cpu}
    import work_precision as wp

    # work_precision's points run the first-order scheme unless they name another
    point = wp.run(wp.Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive", **numerics}))
    errors = wp.lattice_errors(point, reference["result"])
    return {"error": errors["elongation"], "period_error": errors["period"], "cpu_s": point.seconds}


def slope(tolerances: list[float], errors: list[float]) -> float:
    """Least-squares slope of log error against log tolerance."""
    keep = np.asarray(errors) > 0
    return float(np.polyfit(np.log(np.asarray(tolerances)[keep]), np.log(np.asarray(errors)[keep]), 1)[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tolerances", type=float, nargs="+", default=[0.1, 0.01, 0.001, 0.0001])
    parser.add_argument("--cases", nargs="+", default=["disc", "pair", "lattice"], choices=["disc", "pair", "lattice"])
    parser.add_argument("--output", type=Path, default=RESULT)
    args = parser.parse_args()
    refs = references(args.cases)
    out = {"cases": {}}
    if args.output.exists():  # cases measured by an earlier invocation are kept, each with its command
        out["cases"] = json.loads(args.output.read_text()).get("cases", {})
    for case in args.cases:
        rows = []
        for tolerance in args.tolerances:
            rows.append({"tolerance_t": tolerance, **measure(case, tolerance, refs[case])})
            print(json.dumps({"case": case, **rows[-1]}), flush=True)
        out["cases"][case] = {"rows": rows, "slope": slope(args.tolerances, [r["error"] for r in rows]),
                              "reference": {k: v for k, v in refs[case].items() if k != "result"},
                              "command": "python benchmarks/tolerance.py --cases " + case + " --tolerances "
                                         + " ".join(map(str, args.tolerances))}
        if case == "disc":
            out["cases"][case]["spatial_error_lower_bound"] = float(
                np.max(np.abs(np.subtract(refs["disc"]["area_h_0.5"], refs["disc"]["area"]))))
        print(f"{case}: log-log slope of error against tolerance {out['cases'][case]['slope']:.2f}", flush=True)
    args.output.parent.mkdir(exist_ok=True)
    args.output.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
