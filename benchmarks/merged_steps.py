"""Steps merged into one call of the adaptive scheme: what it saves and what it changes.

    python benchmarks/merged_steps.py [--repeats 3] [--shear-time 400] [--no-accuracy]

Since session 12 :meth:`femphase.stepping.Stepper.step` takes ``steps``: the adaptive scheme
(the default) then runs them as one run of substeps, synchronised at the end only, and
:class:`femphase.simulation.Simulation` ends its calls at frames, T1 looks, phase ends and
every ``numerics.merged_steps`` (default 8) steps.

Speed: CPU ms per time unit of shear at the default scheme (outer step 10) with calls of
1, 2 and 8 steps, interleaved (1, 2, 8, 8, 2, 1, … ``--repeats`` times), from the same
relaxed state: the N = 100 lattice of step_time.py (γ̇ = 0.1487) and the random packing of
examples/random.toml (seed 1) at γ̇ = 0.1083. Calls of 2 steps are what the examples take
(their "order" observable looks for T1s every 20 time units); 8 is a run without T1 looks.
Ratios are to the 1-step run next to each.

Accuracy: work_precision.py's lattice problem (relaxed 300, sheared 3600 at 0.1487, default
scheme, outer step 10) run by ``Simulation.run`` with frames every 10 time units (calls of 1
step) and every 80 (calls of 8), and the time reference of ``work_precision.py --schemes``
(sav2 at dt = 0.25, frames every 10). At the common times (every 80): max |r̄ − r̄_ref| /
max r̄_ref of both runs, and of the one against the other. Writes results/merged_steps.json.
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from concurrent.futures import ProcessPoolExecutor

import common  # pins BLAS threads before numpy loads
import numpy as np

from step_time import RESULTS, relaxed_lattice, shear_stepper, step_ms
from work_precision import Point, run

CALLS = (1, 2, 8)
RANDOM_RATE = 0.1083
MERGED_FRAME = 80.0


def speed(repeats: int, shear_time: float) -> dict:
    """{scene: {steps per call: [CPU ms per time unit, …]}} in interleaved runs."""
    simulation, scene, lattice = relaxed_lattice()
    random_scene, random_simulation, packing, _ = common.relaxed_random_packing()
    starts = {"lattice": (lambda state: shear_stepper(simulation, scene, state, 10.0), lattice),
              f"random packing at {RANDOM_RATE}": (lambda state: _random_stepper(random_scene, random_simulation,
                                                                                  state), packing)}
    out = {name: {k: [] for k in CALLS} for name in starts}
    for repeat in range(repeats):
        for k in CALLS + CALLS[::-1]:
            for name, (make, relaxed) in starts.items():
                state = copy.deepcopy(relaxed)
                stepper = make(state)
                ms = step_ms(stepper, state, round(shear_time / (10.0 * k)), time.process_time, k).sum() / shear_time
                out[name][k].append(float(ms))
                print(f"{name}: calls of {k}: {ms:.3f} CPU ms per time unit", flush=True)
    return out


def _random_stepper(scene, simulation, state):
    stepper, _ = common.random_shear_stepper(scene, simulation, state, RANDOM_RATE)
    stepper.step(state)  # set-up
    return stepper


def accuracy() -> dict:
    points = [Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"}),
              Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive"}),
              Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive"}, frame=MERGED_FRAME)]
    with ProcessPoolExecutor(2) as pool:
        reference, every_step, merged = pool.map(run, points)
    times = np.array(merged.result["times"])
    series = {}
    for name, point in (("reference", reference), ("calls of 1", every_step), ("calls of 8", merged)):
        t, r = np.array(point.result["times"]), np.array(point.result["mean_elongation"])
        series[name] = r[np.isin(np.round(t, 6), np.round(times, 6))]
        assert series[name].size == times.size, name
    scale = np.max(np.abs(series["reference"]))
    return {"times": times.tolist(), "cpu_seconds": {"calls of 1": every_step.seconds, "calls of 8": merged.seconds},
            "elongation_error_in_time": {name: float(np.max(np.abs(series[name] - series["reference"])) / scale)
                                         for name in ("calls of 1", "calls of 8")},
            "calls_of_8_against_calls_of_1": float(np.max(np.abs(series["calls of 8"] - series["calls of 1"])) / scale),
            "commands": [p.command() for p in points]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--shear-time", type=float, default=400.0)
    parser.add_argument("--no-accuracy", action="store_true")
    args = parser.parse_args()
    result = {"command": "python benchmarks/merged_steps.py", "speed": speed(args.repeats, args.shear_time)}
    for name, runs in result["speed"].items():
        base = np.array(runs[1])
        for k in CALLS[1:]:
            ratios = np.array(runs[k]) / base
            print(f"{name}: calls of {k} / calls of 1: {np.median(ratios):.3f} "
                  f"[{ratios.min():.3f}–{ratios.max():.3f}] (median {np.median(runs[k]):.3f} ms per time unit)")
    if not args.no_accuracy:
        result["accuracy"] = accuracy()
        a = result["accuracy"]
        print(f"r̄(t) error in time at the common times: calls of 1 {a['elongation_error_in_time']['calls of 1']:.4f}, "
              f"calls of 8 {a['elongation_error_in_time']['calls of 8']:.4f}; "
              f"8 against 1: {a['calls_of_8_against_calls_of_1']:.4f}")
    (RESULTS / "merged_steps.json").write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
