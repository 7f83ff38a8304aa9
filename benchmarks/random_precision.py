"""The adaptive scheme's time error on the sheared random packing (the paper's Fig. 1a set-up).

    python benchmarks/random_precision.py [--rates 0.1083 1] [--shear-time 200]
    python benchmarks/random_precision.py --relaxation
    python benchmarks/random_precision.py --merged 8 [--rates …] [--shear-time 400]

``work_precision.py --schemes`` calibrates the default tolerance on the hexagonal lattice;
this measures what it gives where the paper's order-parameter figures run:
``examples/random.toml`` (seed 1) relaxed by the default scheme for its 2000 time units, then
sheared from that state for ``--shear-time`` time units at each rate by

* the reference: sav2 at fixed dt = 0.125 (second order), checked against sav2 at dt = 0.25
  (their difference bounds the reference's own error: ~1/4 of it);
* the adaptive scheme (outer step 10) at tolerances 1e-1 (the default), 3e-2, 1e-2, 3e-3,
  and the adaptive scheme at 1e-2 with the repulsion not split off.

Errors of the elongation r of every particle at every 10 time units, relative to the
reference's largest r: the largest over particles and frames, and the median. Over
200 time units the trajectories stay close enough for a pointwise comparison; over the
protocol's 10⁵ they decorrelate (the dynamics is chaotic), and only statistics compare.
Substeps are the accepted substeps of the shear; CPU seconds of this process. Writes
``results/random_precision.json`` and the README section.

``--relaxation``: the relaxation itself (no flow, 2000 time units from discs of R/2), whose
end state every shear above starts from: the adaptive scheme at RELAXATION_TOLERANCES
against sav2 at dt = 0.25, the largest |φ − φ_ref| over all nodes, its median over the
particles, and the largest relative difference of a particle's Σ_k φ_k² over the nodes (its
area, up to the wall nodes' half weight); and the reference's own error, against sav2 at
dt = 0.125 and the two extrapolated at order 2, against which each tolerance is measured too.
Printed (benchmarks/README.md, "The default's time error on the random packing", holds the
numbers).
"""

from __future__ import annotations

import argparse
import copy
import json
import time
from dataclasses import replace
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.analysis.shape import shape_observables
from femphase.run.simulation import Simulation

RESULTS = Path(__file__).parent / "results"
FRAME = 10.0
TOLERANCES = (1e-1, 3e-2, 1e-2, 3e-3)
#: (tolerance_t, repulsion_split) of the adaptive scheme with the repulsion not split off
FORMER_DEFAULT = (1e-2, False)
REFERENCE_DT, CHECK_DT = 0.125, 0.25
RELAXATION_TOLERANCES, RELAXATION_REFERENCE_DT = (1e-1, 3e-2, 1e-2, 1e-3), 0.25


def shear(scene, relaxed, rate: float, shear_time: float, dt: float, steps_per_call: int = 1, **numerics) -> dict:
    """r of every particle at every FRAME of shear from ``relaxed`` (with ``steps_per_call``
    > 1: at the end of every call of that many steps), CPU seconds, substeps."""
    state = copy.deepcopy(relaxed)
    state.memory.clear()  # the relaxation's substep counts and level
    simulation = Simulation(replace(scene, numerics=replace(scene.numerics, **numerics)))
    phase = replace(scene.phases[1], dt=dt, duration=shear_time, frame_interval=FRAME,
                    flow={**scene.phases[1].flow, "rate": rate})
    stepper = simulation.stepper(phase, state.radii)
    per_frame = max(round(FRAME / dt), steps_per_call)
    elongation = []
    started = time.process_time()
    for done in range(steps_per_call, phase.n_steps + 1, steps_per_call):
        stepper.step(state, steps_per_call)
        if done % per_frame == 0:
            elongation.append(shape_observables(state).elongation)
    seconds = time.process_time() - started
    counts = state.memory.get("adaptive_counts")
    return {"elongation": np.array(elongation), "seconds": seconds,
            "substeps": None if counts is None else int(counts[0]), "rejected": None if counts is None else int(counts[1])}


def errors(run: dict, reference: dict) -> dict:
    difference = np.abs(run["elongation"] - reference["elongation"]) / np.max(reference["elongation"])
    return {"max": float(difference.max()), "median": float(np.median(difference))}


def report(result: dict) -> str:
    rows = []
    for rate, entry in result["rates"].items():
        check = entry["check"]
        rows.append([rate, f"sav2, dt = {CHECK_DT:g} (reference check)", "–", f"{check['seconds']:.1f}",
                     f"{100 * check['errors']['max']:.2g} %", f"{100 * check['errors']['median']:.2g} %"])
        for row in entry["adaptive"]:
            name = (f"adaptive, tolerance_t {row['tolerance_t']:g}"
                    + ("" if row.get("repulsion_split", False) else ", repulsion unsplit")
                    + (" **(default)**" if row["default"] else ""))
            rows.append([rate, name, f"{row['substeps']} ({row['rejected']})", f"{row['seconds']:.1f}",
                         f"{100 * row['errors']['max']:.2g} %", f"{100 * row['errors']['median']:.2g} %"])
    return "\n".join([
        f"Random packing (`examples/random.toml`, seed 1, relaxed {result['relax_time']:g} time units), "
        f"{result['shear_time']:g} time units of shear from it (`python benchmarks/random_precision.py`); "
        f"errors of r against sav2 at dt = {REFERENCE_DT:g} ({result['reference_seconds']:.0f} CPU s in all).\n",
        common.markdown_table(["γ̇", "scheme", "substeps (rejected)", "CPU s", "r error, largest", "r error, median"],
                              rows)])


def relaxed_fields(dt: float | None = None, **numerics) -> tuple:
    """(scene, (N, nodes) fields, CPU seconds) after the random packing's relaxation phase
    (``common.relaxed_random_packing``)."""
    scene, _, state, seconds = common.relaxed_random_packing(dt, **numerics)
    return scene, np.stack([state.global_field(i) for i in range(len(state.radii))]), seconds


def relaxation() -> None:
    scene, reference, seconds = relaxed_fields(RELAXATION_REFERENCE_DT, scheme="sav2")
    print(f"relaxation of {common.RANDOM_SCENE.name}, {scene.phases[0].duration:g} time units; reference sav2 "
          f"dt = {RELAXATION_REFERENCE_DT:g} ({seconds:.0f} CPU s)", flush=True)
    # the reference's own error: sav2 at half its dt, and the two extrapolated at order 2
    _, finer, seconds = relaxed_fields(RELAXATION_REFERENCE_DT / 2, scheme="sav2")
    extrapolated = finer + (finer - reference) / 3.0
    print(f"its own error: max |φ_ref − φ(dt = {RELAXATION_REFERENCE_DT / 2:g})| {np.abs(finer - reference).max():.3g}, "
          f"max |φ_ref − φ_extrapolated| {np.abs(extrapolated - reference).max():.3g} ({seconds:.0f} CPU s)",
          flush=True)
    area_ref = np.sum(reference**2, axis=1)
    for tolerance in RELAXATION_TOLERANCES:
        _, fields, seconds = relaxed_fields(scheme="adaptive", tolerance_t=tolerance)
        difference = np.abs(fields - reference)
        area = np.sum(fields**2, axis=1)
        print(f"adaptive tolerance_t {tolerance:g}: {seconds:.1f} CPU s, max |φ − φ_ref| {difference.max():.3g}, "
              f"median over particles {np.median(difference.max(axis=1)):.3g}, "
              f"largest area difference {np.max(np.abs(area - area_ref) / area_ref):.2g}; "
              f"max |φ − φ_extrapolated| {np.abs(fields - extrapolated).max():.3g}", flush=True)


def merged(rates: list[float], shear_time: float, steps_per_call: int) -> None:
    """The default scheme in calls of ``steps_per_call`` steps of FRAME (as Simulation.run
    takes them between frames) against calls of one step, both against the reference, at
    the end of every call of the merged run."""
    scene, _, relaxed, _ = common.relaxed_random_packing()
    stride = steps_per_call
    result = {"command": f"python benchmarks/random_precision.py --merged {steps_per_call} --rates "
                         + " ".join(f"{r:g}" for r in rates) + f" --shear-time {shear_time:g}",
              "steps_per_call": steps_per_call, "shear_time": shear_time, "rates": {}}
    for rate in rates:
        reference = shear(scene, relaxed, rate, shear_time, REFERENCE_DT, scheme="sav2")
        single = shear(scene, relaxed, rate, shear_time, FRAME, scheme="adaptive")
        calls = shear(scene, relaxed, rate, shear_time, FRAME, steps_per_call, scheme="adaptive")
        sampled = {"elongation": reference["elongation"][stride - 1::stride]}
        single_sampled = {"elongation": single["elongation"][stride - 1::stride]}
        assert sampled["elongation"].shape == calls["elongation"].shape
        result["rates"][f"{rate:g}"] = {
            "calls of 1": {"seconds": single["seconds"], "substeps": single["substeps"],
                           "errors": errors(single_sampled, sampled)},
            f"calls of {steps_per_call}": {"seconds": calls["seconds"], "substeps": calls["substeps"],
                                           "errors": errors(calls, sampled)},
            "merged against single": errors(calls, single_sampled)}
        entry = result["rates"][f"{rate:g}"]
        print(f"γ̇ = {rate:g}: largest r error at the {sampled['elongation'].shape[0]} common times: calls of 1 "
              f"{entry['calls of 1']['errors']['max']:.4f}, calls of {steps_per_call} "
              f"{entry[f'calls of {steps_per_call}']['errors']['max']:.4f}; between them "
              f"{entry['merged against single']['max']:.4f}; CPU s {single['seconds']:.1f} / {calls['seconds']:.1f}",
              flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "random_precision_merged.json").write_text(json.dumps(result, indent=1) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rates", type=float, nargs="+", default=[0.1083, 1.0])
    parser.add_argument("--shear-time", type=float, default=200.0)
    parser.add_argument("--report", action="store_true", help="only rewrite the README section from the JSON")
    parser.add_argument("--relaxation", action="store_true", help="the relaxation's time error (module docstring)")
    parser.add_argument("--merged", type=int, metavar="K",
                        help="the default in calls of K steps against calls of 1, at the end of every call "
                             "(results/random_precision_merged.json)")
    args = parser.parse_args()
    if args.relaxation:
        relaxation()
        return
    if args.merged:
        merged(args.rates, args.shear_time, args.merged)
        return
    out = RESULTS / "random_precision.json"
    if args.report:
        common.update_readme("random_precision", report(json.loads(out.read_text())))
        return
    from femphase.config import Numerics

    scene, _, relaxed, _ = common.relaxed_random_packing()
    result = {"relax_time": scene.phases[0].duration, "shear_time": args.shear_time, "rates": {},
              "reference_seconds": 0.0, "command": "python benchmarks/random_precision.py"}
    for rate in args.rates:
        reference = shear(scene, relaxed, rate, args.shear_time, REFERENCE_DT, scheme="sav2")
        check = shear(scene, relaxed, rate, args.shear_time, CHECK_DT, scheme="sav2")
        result["reference_seconds"] += reference["seconds"]
        entry = {"check": {"seconds": check["seconds"], "errors": errors(check, reference)}, "adaptive": []}
        defaults = Numerics()
        for tolerance, split in [(t, True) for t in TOLERANCES] + [FORMER_DEFAULT]:
            run = shear(scene, relaxed, rate, args.shear_time, FRAME, scheme="adaptive", tolerance_t=tolerance,
                        repulsion_split=split)
            entry["adaptive"].append({"tolerance_t": tolerance, "repulsion_split": split,
                                      "default": (tolerance, split) == (defaults.tolerance_t, defaults.repulsion_split),
                                      "substeps": run["substeps"], "rejected": run["rejected"],
                                      "seconds": run["seconds"], "errors": errors(run, reference)})
        result["rates"][f"{rate:g}"] = entry
    RESULTS.mkdir(exist_ok=True)
    out.write_text(json.dumps(result, indent=1) + "\n")
    markdown = report(result)
    print(markdown)
    common.update_readme("random_precision", markdown)


if __name__ == "__main__":
    main()
