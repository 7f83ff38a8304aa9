"""Does the adaptive scheme's error estimate contain the error its step makes?

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 \\
        python benchmarks/estimate_quality.py [--sizes 3.3333333333 1.6666666667] [--along-shear] [--report]

The adaptive scheme accepts a substep of h when its embedded estimate, max |φ¹ − (2φ̄ − φ⁰)|
(the first-order step's local error, :meth:`femphase.timestepping.sav2.RelaxedSAV2.relax`),
is below the tolerance. This measures, at states sampled from the default run of each case
of ``tolerance.py`` (the disc relaxing from R/2, the pair drifting apart, the lattice
sheared at γ̇ = 0.1487), one sav2 step of h from that state (Strang around the relaxation
under flow, as the substep) against two steps of h/2 from it: the step's local error is
4/3 of their largest difference over all nodes (step doubling at order 2), which contains
every error the step makes, splitting included. Reported per case and h: the ratio of the
embedded estimate to that local error at each sampled state (its median and range). A
ratio ≥ 1 means the estimate bounds the step's error; below 1 it misses part of it. All in
double precision. Writes results/estimate_quality.json; ``--report`` rewrites the README
section from it.

``--along-shear``: the same two numbers at h = 10/3 (the default's substep) every 30 time
units along the shear of examples/hexagonal.toml (γ̇ = 0.1487) from t = 2420 to 3560,
through its first T1 events (the frames' ``t1_count`` beside them): does the step's error
rise where the neighbours exchange? Writes results/estimate_along_shear.json and its README
section; with ``--report``, only the section, from that file.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np
import tolerance

from femphase.run.simulation import Simulation, Tracker
from femphase.state import State
from femphase.timestepping.stepper import Stepper

ROOT = Path(__file__).resolve().parents[1]
RESULT = Path(__file__).resolve().parent / "results" / "estimate_quality.json"
ALONG_SHEAR_RESULT = RESULT.with_name("estimate_along_shear.json")
#: The hexagonal example's frames sampled by ``--along-shear`` (its shear starts at t = 2000)
ALONG_SHEAR = tuple(2000.0 + 30.0 * k for k in range(14, 53))
#: The states sampled in each case: the frames at these times (time units)
SAMPLES = {"disc": (10.0, 20.0, 50.0), "pair": (1000.0, 5000.0, 10000.0, 19000.0),
           "lattice": tuple(300.0 + 400.0 * k for k in range(1, 9))}


class Sampler(Tracker):
    """Copies of the state at the frames at ``times``."""

    def __init__(self, times: tuple[float, ...]) -> None:
        self.times, self.states = times, []

    def frame(self, frame) -> None:
        if any(abs(frame.state.time - t) < 1e-9 for t in self.times):
            self.states.append(frame.state.copy())


def scene_of(case: str):
    if case == "disc":
        return tolerance.disc_scene({}, 10.0)
    if case == "pair":
        return tolerance.pair_scene({}, 10.0)
    import work_precision as wp

    return wp.scene_for(wp.Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive"}))


def estimate_and_error(scene, state: State, h: float) -> tuple[float, float]:
    """(the embedded estimate of one sav2 step of h from ``state``, that step's local error
    by step doubling)."""
    phase = scene.phases[state.phase]
    numerics = replace(scene.numerics, scheme="sav2", precision="double")

    def stepper(dt: float) -> Stepper:
        return Stepper(scene.domain, scene.model, numerics, dt, scene.flow(phase), state.radii, scheme="sav2")

    one = stepper(h)
    scheme, (layout, phi) = one.scheme, state.flat()
    if scheme.half is not None:
        phi, layout = scheme.half.advect(phi, layout, state.time)
    _, _, estimate = scheme.relax(phi, layout, state.time, state.radii, scheme.auxiliary(phi, layout, state), h)
    single, double = state.copy(), state.copy()
    one.step(single, 1)
    stepper(0.5 * h).step(double, 2)
    difference = max(float(np.max(np.abs(single.global_field(i) - double.global_field(i))))
                     for i in range(state.n_particles))
    return estimate, 4.0 / 3.0 * difference


def measure(case: str, sizes: list[float]) -> dict:
    scene = scene_of(case)
    sampler = Sampler(SAMPLES[case])
    Simulation(scene).run(scene.initial_state(), [sampler])
    rows = []
    for h in sizes:
        pairs = [estimate_and_error(scene, state, h) for state in sampler.states]
        ratios = [estimate / error for estimate, error in pairs]
        rows.append({"h": h, "times": [s.time for s in sampler.states], "estimates": [p[0] for p in pairs],
                     "errors": [p[1] for p in pairs], "ratio_median": float(np.median(ratios)),
                     "ratio_min": float(np.min(ratios)), "ratio_max": float(np.max(ratios))})
        print(json.dumps({"case": case, **rows[-1]}), flush=True)
    return {"rows": rows}


def along_shear(h: float) -> dict:
    """The estimate and the local error of one step of ``h`` at ALONG_SHEAR's states of
    examples/hexagonal.toml, with the T1 count of each state's frame."""
    from femphase.run.trackers import FrameRecorder
    from femphase.scene import load_scene

    scene = load_scene(ROOT / "examples" / "hexagonal.toml",
                       ["phases.1.duration=1600", "phases.1.frame_interval=30", "output.fields=false"])
    sampler, recorder = Sampler(ALONG_SHEAR), FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [sampler, recorder])
    t1_counts = dict(zip(recorder.times.tolist(), recorder.series("t1_count", "global").tolist()))
    rows = []
    for state in sampler.states:
        estimate, error = estimate_and_error(scene, state, h)
        rows.append({"time": state.time, "estimate": estimate, "error": error, "t1_count": t1_counts[state.time]})
        print(json.dumps(rows[-1]), flush=True)
    return {"h": h, "rows": rows, "command": "python benchmarks/estimate_quality.py --along-shear"}


def along_shear_report(result: dict) -> str:
    rows = result["rows"]
    errors = np.array([row["error"] for row in rows])
    ratios = np.array([row["estimate"] / row["error"] for row in rows])
    quiet = errors[[row["t1_count"] == rows[0]["t1_count"] for row in rows]]
    return (f"examples/hexagonal.toml sheared at γ̇ = 0.1487, one sav2 step of h = {result['h']:.3g} from the "
            f"frames every 30 time units at t = {rows[0]['time']:g} … {rows[-1]['time']:g} (T1 count "
            f"{rows[0]['t1_count']:g} at the first, {rows[-1]['t1_count']:g} at the last): local error "
            f"{errors.min():.3g}–{errors.max():.3g} ({quiet.min():.3g}–{quiet.max():.3g} before the first "
            f"exchange), estimate / local error {ratios.min():.2f}–{ratios.max():.2f}.\n\n"
            f"Command: `{result['command']}`.")


def report(result: dict) -> str:
    lines = ["| case | h | estimate / local error: median (range) | local error, median |", "|---|---|---|---|"]
    for case, entry in result["cases"].items():
        for row in entry["rows"]:
            lines.append(f"| {tolerance.CASE_NAMES[case].split(' (')[0]} | {row['h']:.3g} | "
                         f"{row['ratio_median']:.2g} ({row['ratio_min']:.2g}–{row['ratio_max']:.2g}) | "
                         f"{np.median(row['errors']):.2g} |")
    return "\n".join(lines) + f"\n\nCommand: `{result['command']}`."


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=float, nargs="+", default=[10.0 / 3.0, 10.0 / 6.0])
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    parser.add_argument("--along-shear", action="store_true", help="sample the hexagonal example's shear instead")
    args = parser.parse_args()
    if args.along_shear:
        if args.report:
            result = json.loads(ALONG_SHEAR_RESULT.read_text())
        else:
            result = along_shear(10.0 / 3.0)
            ALONG_SHEAR_RESULT.write_text(json.dumps(result, indent=1) + "\n")
        common.update_readme("estimate_along_shear", along_shear_report(result))
        return
    if args.report:
        common.update_readme("estimate_quality", report(json.loads(RESULT.read_text())))
        return
    result = {"cases": {case: measure(case, args.sizes) for case in SAMPLES},
              "command": "python benchmarks/estimate_quality.py"}
    RESULT.write_text(json.dumps(result, indent=1) + "\n")
    common.update_readme("estimate_quality", report(result))


if __name__ == "__main__":
    main()
