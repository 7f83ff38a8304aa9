"""Where the adaptive scheme's error estimate peaks, and what sets its substep there.

    python benchmarks/estimate_location.py

The default scheme (``adaptive``) accepts a substep while its estimate, the max-norm over
all positions of |φ¹ − (2φ̄ − φ⁰)| (first- against second-order result,
:meth:`femphase.schemes.RelaxedSAV2.relax`), is below ``numerics.tolerance_t``. This records,
for every substep tried, the position of that maximum: the field's own value φ_i there, the
other fields' Σ_{j≠i} φ_j², and the repulsion's decay rate of φ_i there,
c = J0 · 4κ/λ · Σ_{j≠i} φ_j² (the repulsion's δF/δφ_i is c φ_i / J0, linear in φ_i). A
position is a *tail inside a neighbour* where φ_i < 0.5 and Σ_{j≠i} φ_j² > 0.5. The estimate
without those positions is recorded as well: the substep the rest of the dynamics would
allow.

This was measured on the explicit midpoint step at its default tolerance 1e-2
(``numerics.repulsion_split = false``: the default before session 8), and it is why the
repulsion is now split off; the same runs at the default (split, 3e-2) give the substeps it
allows, which is all this script records of them.

Problems: the lattice of ``work_precision.py --schemes`` (relaxed 300, sheared at
γ̇ = 0.1487 for 1500 time units: past its first T1 peak) and the random packing of
``step_time.py`` (relaxed, then sheared 300 time units at γ̇ = 0.0161 and 1). The estimate
is recomputed alongside the scheme's (the predictor again, deterministic), so the run itself
is the default's. Writes ``results/estimate_location.json`` and the README section.
"""

from __future__ import annotations

import copy
import json
from dataclasses import replace
from pathlib import Path

import common
import numpy as np

from femphase import schemes
from femphase.energy import WindowedFields
from femphase.scene import scene_from_dict
from femphase.simulation import Simulation

RESULTS = Path(__file__).parent / "results"
LATTICE_RATE, LATTICE_RELAX, LATTICE_SHEAR = 0.1487, 300.0, 1500.0
RANDOM_RATES, RANDOM_SHEAR = (0.0161, 1.0), 300.0


def numerics(split: bool) -> dict:
    """The default (split), or the default before session 8 (unsplit, tolerance_t 1e-2)."""
    return {} if split else {"repulsion_split": False, "tolerance_t": 1e-2}


class EstimateRecorder:
    """Wraps RelaxedSAV2.relax while active; one record per substep tried."""

    def __init__(self, locate: bool) -> None:
        self.records: list[dict] = []
        self.locate = locate  # where the estimate peaks (the unsplit step only: it is recomputed)
        self._relax = schemes.RelaxedSAV2.relax

    def __enter__(self) -> "EstimateRecorder":
        recorder, relax = self, self._relax

        def recording(scheme, phi, layout, time, radii, r, dt, **decays):
            new, r_next, estimate = relax(scheme, phi, layout, time, radii, r, dt, **decays)
            recorder.record(scheme, phi, layout, time, radii, dt, new, estimate)
            return new, r_next, estimate

        schemes.RelaxedSAV2.relax = recording
        return self

    def __exit__(self, *exc) -> None:
        schemes.RelaxedSAV2.relax = self._relax

    def record(self, scheme, phi, layout, time, radii, dt, new, estimate) -> None:
        if not self.locate:
            self.records.append({"dt": dt, "estimate": estimate})
            return
        stepper = scheme.stepper
        fields = WindowedFields(phi, layout, radii)
        midpoint = schemes.linearly_implicit_step(stepper, phi, layout, radii, 0.5 * dt,
                                                  scheme.predictor_stabilisation(dt), time + 0.5 * dt, fields)
        error = np.abs(new - 2.0 * midpoint + phi)
        at = int(np.argmax(error))
        others = fields.others_squared
        tails = (phi < 0.5) & (others > 0.5)
        repulsion = next(t for t in stepper.energy.terms if t.name == "repulsion")
        rate = stepper.mobility * 4.0 * repulsion.repulsion / repulsion.interface_width
        self.records.append({
            "dt": dt, "estimate": estimate, "recomputed": float(error[at]), "phi": float(phi[at]),
            "others_squared": float(others[at]), "decay_rate": rate * float(others[at]), "tail": bool(tails[at]),
            "estimate_without_tails": float(error[~tails].max()) if (~tails).any() else 0.0,
        })


def summary(records: list[dict], tolerance: float) -> dict:
    column = {key: np.array([r[key] for r in records]) for key in records[0]}
    sizes, counts = np.unique(column["dt"], return_counts=True)
    out = {"substeps_tried": len(records), "substep_sizes": {f"{s:g}": int(c) for s, c in zip(sizes, counts)},
           "estimate_median": float(np.median(column["estimate"])), "tolerance": tolerance}
    if "tail" not in column:
        return out
    tail = column["tail"]
    return {
        **out,
        "recomputed_matches": bool(np.allclose(column["recomputed"], column["estimate"], rtol=1e-9, atol=1e-15)),
        "tail_share": float(tail.mean()),
        "phi_at_max_median": float(np.median(column["phi"])),
        "others_squared_at_max_median": float(np.median(column["others_squared"])),
        "decay_rate_times_dt_at_tail_max_median": float(np.median((column["decay_rate"] * column["dt"])[tail]))
        if tail.any() else None,
        "without_tails_over_estimate_median": float(np.median(column["estimate_without_tails"] / column["estimate"])),
    }


def run_lattice(split: bool) -> tuple[list[dict], float]:
    scene = scene_from_dict({
        "name": "estimate location lattice", "domain": {"Lx": 70.0, "Ly": 240.0, "h": 1.0},
        "particles": {"layout": "hexagonal", "N": 100}, "output": {"fields": False},
        "numerics": numerics(split),
        "phases": [{"name": "relax", "duration": LATTICE_RELAX, "dt": 10.0, "frame_interval": LATTICE_RELAX},
                   {"name": "shear", "duration": LATTICE_SHEAR, "dt": 10.0, "frame_interval": LATTICE_SHEAR,
                    "flow": {"type": "shear", "rate": LATTICE_RATE}}],
    })
    simulation, state = Simulation(scene), scene.initial_state()
    relax, shear = (simulation.stepper(phase, state.radii) for phase in scene.phases)
    for _ in range(scene.phases[0].n_steps):
        relax.step(state)
    shear.scheme.start_phase(state)
    with EstimateRecorder(locate=not split) as recorder:
        for _ in range(scene.phases[1].n_steps):
            shear.step(state)
    return recorder.records, shear.numerics.tolerance_t


def run_random(split: bool) -> dict[float, tuple[list[dict], float]]:
    scene, _, relaxed, _ = common.relaxed_random_packing()
    simulation = Simulation(replace(scene, numerics=replace(scene.numerics, **numerics(split))))
    out = {}
    for rate in RANDOM_RATES:
        state = copy.deepcopy(relaxed)
        stepper, phase = common.random_shear_stepper(scene, simulation, state, rate)
        with EstimateRecorder(locate=not split) as recorder:
            for _ in range(round(RANDOM_SHEAR / phase.dt)):
                stepper.step(state)
        out[rate] = (recorder.records, stepper.numerics.tolerance_t)
    return out


def sizes(entry: dict) -> str:
    return ", ".join(f"{size} × {count}" for size, count in entry["substep_sizes"].items())


def table(results: dict) -> str:
    rows = []
    for name, s in results["unsplit"].items():
        tail_rate = s["decay_rate_times_dt_at_tail_max_median"]
        split = results["split"][name]
        rows.append([name, sizes(s), f"{s['estimate_median']:.2g}", f"{100 * s['tail_share']:.0f} %",
                     f"{s['phi_at_max_median']:.3f}", f"{s['others_squared_at_max_median']:.2f}",
                     "–" if tail_rate is None else f"{tail_rate:.2f}",
                     f"{s['without_tails_over_estimate_median']:.2f}", sizes(split), f"{split['estimate_median']:.2g}"])
    return common.markdown_table(
        ["problem", "unsplit: substeps tried (size × count)", "estimate, median", "max in a tail inside a neighbour",
         "φ_i at the max, median", "Σ_{j≠i} φ_j² there, median", "c·dt at a tail max, median",
         "estimate without tails / estimate, median", "split: substeps tried", "estimate, median"], rows)


def main() -> None:
    results: dict = {"unsplit": {}, "split": {}}
    for split in (False, True):
        key = "split" if split else "unsplit"
        records, tolerance = run_lattice(split)
        results[key][f"lattice, γ̇ = {LATTICE_RATE:g}"] = summary(records, tolerance)
        for rate, (records, tolerance) in run_random(split).items():
            results[key][f"random packing, γ̇ = {rate:g}"] = summary(records, tolerance)
    if not all(s["recomputed_matches"] for s in results["unsplit"].values()):
        raise AssertionError("the recomputed estimate differs from the scheme's: the recorder no longer "
                             "mirrors RelaxedSAV2.relax")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "estimate_location.json").write_text(json.dumps(
        {"results": results, "command": "python benchmarks/estimate_location.py"}, indent=1) + "\n")
    markdown = "\n".join([
        "Where the adaptive scheme's estimate peaks (`python benchmarks/estimate_location.py`): the lattice "
        f"sheared {LATTICE_SHEAR:g} time units after {LATTICE_RELAX:g} of relaxation, the random packing "
        f"{RANDOM_SHEAR:g} time units after its relaxation; unsplit at tolerance_t 1e-2 (the default before "
        "session 8), split at the default.\n", table(results)])
    print(markdown)
    common.update_readme("estimate_location", markdown)


if __name__ == "__main__":
    main()
