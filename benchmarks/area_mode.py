"""What the area-mode ceiling costs and buys: the adaptive scheme with the area term's
rank-one mode explicit (the default, substeps below 1.5/c) against the mode linearly implicit
in the predictor (``numerics.area_implicit``: the ceiling 4/c, docs/decisions/0050; the
stored results were measured before it, without a ceiling, at the commits they name).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/area_mode.py

Variants of the adaptive scheme (dt = 10):

* ``explicit``: the default;
* ``implicit``: ``area_implicit = true``, Sherman–Morrison with w = A⁻¹M_Lφ (one more solve
  per substep, :meth:`femphase.timestepping.sav2.RelaxedSAV2.rank_one_predictor`);
* ``solve-free``: the same with w replaced by φ/(1/τ + J0 S), A⁻¹ without its stiffness
  part (a prototype defined here, not in femphase: no solve, a response ρ ≥ 1 too large by
  1.7–4 % at substeps 2.5–10 on the lattice, docs/decisions/0022-area-mode-ceiling-kept.md);
* ``split``: under flow the area term split off the midpoint step with the repulsion and
  integrated exactly (a prototype defined here, :func:`area_flow`; no rank-one mode is left
  in the step, so no ceiling; without flow nothing is split and it is the default;
  docs/decisions/0025-area-term-split-not-kept.md);
* ``exponential``: no ceiling, and the midpoint step's area force taken at an effective area
  ratio that moves the rank-one mode by e^(−z), z = c·h, instead of the explicit midpoint
  rule's 1 − z + z²/2 (a prototype defined here, :func:`exponential_predictor`; no solve).

Cases and errors in time, against time-converged references at the same h = 1:

* ``disc``, ``pair``, ``lattice``: ``benchmarks/tolerance.py``'s (its cached references);
* ``random``: ``benchmarks/random_precision.py``'s 200 time units of shear of the relaxed
  random packing at γ̇ = 0.1083 and 1 (largest r error relative to max r, substeps);
* ``stiff``: one disc of R = 8 with μ × 10 (a 10× faster area mode) in a 40 × 40 channel
  sheared at u = 2y/40 for 30 time units (max |φ − φ_ref| and the relative area error
  against sav2 at dt = 0.05 in double precision).

CPU seconds of this process for each run. Writes ``results/area_mode.json`` (``--output``)
and prints a row per run; ``--variants`` and ``--cases`` choose a part, e.g.

    python benchmarks/area_mode.py --variants explicit split --cases lattice random stiff \
        --output area_split.json
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np
import random_precision
import tolerance
import work_precision as wp

from femphase.model.energy import AreaTerm, FreeEnergy, WindowedFields
from femphase.run.simulation import Simulation
from femphase.run.trackers import FrameRecorder
from femphase.scene import scene_from_dict
from femphase.timestepping.adaptive import AdaptiveSAV2
from femphase.timestepping.sav2 import RelaxedSAV2

RESULT = Path(__file__).parent / "results" / "area_mode.json"
VARIANTS = {"explicit": {}, "implicit": {"area_implicit": True}, "solve-free": {"area_implicit": True}, "split": {}, "exponential": {}}
TOLERANCES = {"disc": (0.1, 0.03), "pair": (0.1, 0.03, 0.01, 1e-3, 1e-4), "lattice": (0.1, 0.05, 0.03),
              "random": (0.1, 0.05, 0.03), "stiff": (0.1, 0.01)}
EXACT_PREDICTOR = RelaxedSAV2.rank_one_predictor
SPLIT_DECAY, DECAY = FreeEnergy.split_decay, RelaxedSAV2.decay
PREDICTOR, LARGEST_SUBSTEP = RelaxedSAV2._predictor, AdaptiveSAV2.largest_substep


def solve_free_predictor(self, explicit, fields, dt, stabilisation):
    """rank_one_predictor with w = φ/(1/dt + J0 S) instead of A⁻¹M_Lφ (module docstring)."""
    phi, layout, j0 = fields.phi, fields.layout, self.stepper.mobility
    coefficient = j0 * self.reacting.rank_one_coefficient(fields)
    w = phi / (1.0 / dt + j0 * stabilisation)
    weighted = layout.mass * phi
    change = layout.reduce(np.add, weighted * (explicit - phi))
    shift = coefficient * change / (1.0 + coefficient * layout.reduce(np.add, weighted * w))
    return explicit - fields.on_positions(shift) * w


def stiff_scene(numerics: dict, dt: float):
    return scene_from_dict({
        "name": "stiff disc", "domain": {"Lx": 40.0, "Ly": 40.0, "h": 1.0}, "model": {"mu": 200.0},
        "particles": {"layout": "single", "centres": [[20.0, 20.0]], "initial_radius": 8.0},
        "numerics": numerics, "output": {"fields": False, "checkpoint": False},
        "phases": [{"name": "shear", "duration": 30.0, "dt": dt, "frame_interval": 30.0,
                    "flow": {"type": "shear", "rate": 2.0}}]})


def stiff_run(numerics: dict, dt: float) -> tuple[np.ndarray, float, float, int]:
    """(φ at t = 30, its area ∫φ², CPU seconds, accepted substeps (0 for fixed-dt schemes))."""
    scene = stiff_scene(numerics, dt)
    state = scene.initial_state()
    started = time.process_time()
    Simulation(scene).run(state, [FrameRecorder()])
    phi = state.global_field(0)
    substeps = int(state.memory.get("adaptive_counts", [0])[0])
    return phi, float(scene.domain.operators.lumped_mass @ phi**2), time.process_time() - started, substeps


def measure(case: str, numerics: dict, refs: dict, random_state) -> dict:
    if case == "disc":
        areas, cpu, _ = tolerance.disc_areas(numerics, 10.0)
        return {"error": float(np.abs(np.subtract(areas, refs["disc"]["area"])).max()), "cpu_s": cpu}
    if case == "pair":
        separation, cpu, _ = tolerance.pair_separation(numerics, 10.0)
        return {"error": abs(separation - refs["pair"]["separation"]), "cpu_s": cpu}
    if case == "lattice":
        point = wp.run(wp.Point("lattice", "fem", 1.0, 10.0, {"scheme": "adaptive", **numerics}))
        errors = wp.lattice_errors(point, refs["lattice"]["result"])
        return {"error": errors["elongation"], "period_error": errors["period"], "cpu_s": point.seconds}
    if case == "random":
        scene, relaxed, references = random_state
        out = {}
        for rate, reference in references.items():
            run = random_precision.shear(scene, relaxed, rate, 200.0, random_precision.FRAME, scheme="adaptive",
                                         **numerics)
            out[f"{rate:g}"] = {"error": random_precision.errors(run, reference)["max"], "substeps": run["substeps"],
                                "cpu_s": run["seconds"]}
        return out
    phi, area, cpu, substeps = stiff_run(numerics, 10.0)
    reference, reference_area = refs["stiff"]
    return {"error": float(np.abs(phi - reference).max()), "area_error": abs(area / reference_area - 1.0),
            "substeps": substeps, "cpu_s": cpu}


def split_with_area(self):
    """FreeEnergy.split_decay with the area term among the split-off terms (``split``)."""
    decaying = tuple(t for t in self.terms if t.decays or isinstance(t, AreaTerm))
    return FreeEnergy([t for t in self.terms if t not in decaying]), decaying


def area_flow(phi, layout, radii, area: AreaTerm, mobility: float, dt: float):
    """φ after ``dt`` of the area term alone, exactly: ∂tφ_i = J0 (4μ/πR_i²)(1 − a_i) φ_i scales
    each field uniformly, and its area ratio a_i = (M_L φ_i)ᵀφ_i/πR_i² follows the logistic
    equation da/dt = k a (1 − a), k = 8 J0 μ/πR_i², so a(dt) = 1/(1 + (1/a − 1) e^{−k dt}) and
    φ_i ← φ_i √(a(dt)/a)."""
    fields = WindowedFields(phi, layout, radii)
    ratio = fields.area_ratio
    rate = 8.0 * mobility * area.area_stiffness / (np.pi * fields.radius**2)
    after = 1.0 / (1.0 + (1.0 / ratio - 1.0) * np.exp(-rate * dt))
    return phi * fields.on_positions(np.sqrt(after / ratio).astype(phi.dtype))


def decay_with_area(self, phi, layout, radii, dt):
    """RelaxedSAV2.decay with the area term's exact flow over dt/2 before and after the
    other decay terms' (Strang; ``split``)."""
    areas = [t for t in self.decaying if isinstance(t, AreaTerm)]
    if not areas or dt == 0.0:
        return DECAY(self, phi, layout, radii, dt)
    phi = area_flow(phi, layout, radii, areas[0], self.stepper.mobility, 0.5 * dt)
    everything, self.decaying = self.decaying, tuple(t for t in self.decaying if t not in areas)
    try:
        phi = DECAY(self, phi, layout, radii, dt) if self.decaying else phi
    finally:
        self.decaying = everything
    return area_flow(phi, layout, radii, areas[0], self.stepper.mobility, 0.5 * dt)


def exponential_predictor(self, phi, layout, time, radii, dt):
    """RelaxedSAV2._predictor whose φ̄ carries an effective area ratio for the step's area
    force (``exponential``). Per particle, e = a − 1 obeys de/dt = −c e + N near a steady
    state, c = J0 β_i (M_L φ_i)ᵀφ_i the rank-one mode's rate and N what the other terms do to
    the area. The exponential midpoint rule gives e¹ = e^(−z) e⁰ + h φ1(−z) N, z = c h,
    φ1(−z) = (1 − e^(−z))/z; the midpoint step gives e¹ = e⁰ + h (N − c e_used), so
    e_used = e⁰ + (1 − φ1(−z)) (N/c − e⁰). The predictor's Euler half step, with the
    stabilisation S that damps every mode by 1 + J0 S h/2, gives N/c − e⁰ = 2 Δ/z with
    Δ = (ē − e⁰)(1 + J0 S h/2). Without the other terms e¹ = e^(−z) e⁰ at any z, and a
    steady state (N = c e⁰) stays steady; as z → 0, e_used → ē, the explicit rule."""
    midpoint, middle = PREDICTOR(self, phi, layout, time, radii, dt)
    start, j0 = WindowedFields(phi, layout, radii), self.stepper.mobility
    z = j0 * self.reacting.rank_one_coefficient(start) * start.areas * dt
    change = (middle.area_ratio - start.area_ratio) * (1.0 + 0.5 * dt * j0 * self.predictor_stabilisation(dt))
    slowdown = np.where(z > 1e-8, -np.expm1(-z) / np.maximum(z, 1e-300), 1.0 - 0.5 * z)  # φ1(−z)
    weight = np.where(z > 1e-8, 2.0 * (1.0 - slowdown) / np.maximum(z, 1e-300), 1.0 - z / 3.0)
    middle.__dict__["area_ratio"] = start.area_ratio + weight * change  # the cached property's slot
    return midpoint, middle


def use_variant(variant: str) -> None:
    """Patch femphase for ``variant``'s prototypes (none for the others)."""
    RelaxedSAV2.rank_one_predictor = solve_free_predictor if variant == "solve-free" else EXACT_PREDICTOR
    FreeEnergy.split_decay = split_with_area if variant == "split" else SPLIT_DECAY
    RelaxedSAV2.decay = decay_with_area if variant == "split" else DECAY
    RelaxedSAV2._predictor = exponential_predictor if variant == "exponential" else PREDICTOR
    # the prototypes leave no rank-one mode in the step, and ``split`` puts the area term
    # among the decays, which has no pointwise rate: no ceiling for either
    AdaptiveSAV2.largest_substep = ((lambda self, *args: np.inf) if variant in ("exponential", "split")
                                    else LARGEST_SUBSTEP)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS)[:3])
    parser.add_argument("--cases", nargs="+", choices=list(TOLERANCES), default=list(TOLERANCES))
    parser.add_argument("--output", default=RESULT.name, help="file name in results/ (default area_mode.json)")
    args = parser.parse_args()
    refs = tolerance.references(["disc", "pair", "lattice"])
    phi, area, *_ = stiff_run({"scheme": "sav2", "precision": "double"}, 0.05)
    refs["stiff"] = (phi, area)
    random_state = None
    if "random" in args.cases:
        scene, _, relaxed, _ = common.relaxed_random_packing()
        random_state = (scene, relaxed, {rate: random_precision.shear(scene, relaxed, rate, 200.0,
                                                                      random_precision.REFERENCE_DT, scheme="sav2")
                                         for rate in (0.1083, 1.0)})
    command = "python benchmarks/area_mode.py" + "".join(
        f" --{name} {' '.join(value)}" for name, value in (("variants", args.variants), ("cases", args.cases))
        if value != parser.get_default(name))
    if args.output != RESULT.name:
        command += f" --output {args.output}"
    result = {"command": command, "variants": args.variants, "cases": {}}
    for case in args.cases:
        rows = []
        for variant in args.variants:
            use_variant(variant)
            options = VARIANTS[variant]
            for tolerance_t in TOLERANCES[case]:
                rows.append({"variant": variant, "tolerance_t": tolerance_t,
                             **measure(case, {"tolerance_t": tolerance_t, **options}, refs, random_state)})
                print(json.dumps({"case": case, **rows[-1]}), flush=True)
        result["cases"][case] = rows
    use_variant("explicit")
    RESULT.parent.mkdir(exist_ok=True)
    (RESULT.parent / args.output).write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
