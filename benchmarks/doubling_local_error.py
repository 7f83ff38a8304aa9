"""Do the adaptive scheme's estimates contain the local error of its substep?

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/doubling_local_error.py

Two discs of R = 8 with centres 12 apart in a 40 × 40 channel, relaxed for 50 time units
without flow (sav2 at dt = 0.25), then one substep of h under shear (γ̇ = 1, u = γ̇ y/Ly) by
the adaptive scheme, its first size forced to h and a tolerance it meets, in double
precision: the substep's estimate (the doubled one converted from per time unit to per
substep) against its local error, max |φ − φ_ref| over both fields, φ_ref by sav2 at h/128
from the same state. At the paper's κ and at κ × 10, where the split repulsion's decay
carries much of the step's error; with the embedded estimate and with step doubling. Writes
results/doubling_local_error.json and its README section.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import numpy as np

from femphase.config import Numerics
from femphase.flows import linear_shear
from femphase.model.parameters import ModelParameters
from femphase.scene import scene_from_dict
from femphase.timestepping.stepper import Stepper

RESULT = Path(__file__).resolve().parent / "results" / "doubling_local_error.json"


def relaxed_pair(params: ModelParameters):
    scene = scene_from_dict({"domain": {"Lx": 40.0, "Ly": 40.0},
                             "particles": {"layout": "list", "centres": [[14.0, 20.0], [26.0, 20.0]],
                                           "initial_radius": 8.0},
                             "phases": [{"duration": 50.0, "dt": 0.25, "frame_interval": 50.0}]})
    domain, state = scene.domain, scene.initial_state()
    Stepper(domain, params, Numerics(scheme="sav2", precision="double"), 0.25, None, state.radii).step(state, 200)
    return domain, replace(state, time=0.0, step=0, memory={})


def one_substep(domain, start, params, estimate: str, h: float):
    """(the state after one adaptive substep of h, its estimate per substep)."""
    state = start.copy()
    numerics = Numerics(estimate=estimate, precision="double", tolerance_t=0.5, merged_steps=1)
    stepper = Stepper(domain, params, numerics, h, linear_shear(1.0, 40.0), state.radii)
    state.memory["adaptive_divisions"] = np.array([1, 0])
    stepper.step(state)
    per_substep = h if estimate == "doubling" else 1.0
    return state, float(state.memory["adaptive_error"][0]) * per_substep, state.memory["adaptive_counts"].tolist()


def main() -> None:
    rows = []
    for kappa in (0.5, 5.0):
        params = replace(ModelParameters(), repulsion=kappa)
        domain, start = relaxed_pair(params)
        for h in (0.5, 1.0):
            reference = start.copy()
            Stepper(domain, params, Numerics(scheme="sav2", precision="double"), h / 128, linear_shear(1.0, 40.0),
                    reference.radii).step(reference, 128)
            for estimate in ("embedded", "doubling"):
                state, value, counts = one_substep(domain, start, params, estimate, h)
                error = max(float(np.abs(state.global_field(i) - reference.global_field(i)).max()) for i in range(2))
                rows.append({"kappa": kappa, "h": h, "estimate": estimate, "value": value,
                             "local_error": error, "ratio": value / error, "substeps": counts})
                print(json.dumps(rows[-1]), flush=True)
    result = {"rows": rows, "command": "python benchmarks/doubling_local_error.py"}
    RESULT.write_text(json.dumps(result, indent=1) + "\n")
    common.update_readme("doubling_local_error", report(result))


def report(result: dict) -> str:
    lines = ["| κ | h | estimate | estimate / local error | local error |", "|---|---|---|---|---|"]
    for row in result["rows"]:
        lines.append(f"| {row['kappa']:g} | {row['h']:g} | {row['estimate']} | {row['ratio']:.2f} | "
                     f"{row['local_error']:.2g} |")
    return "\n".join(lines) + f"\n\nCommand: `{result['command']}`."


if __name__ == "__main__":
    main()
