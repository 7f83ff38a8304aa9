"""A disc translating in uniform flow on a Delaunay mesh: the meshes' advection steps.

    python verification/mesh_advection.py        # ~10 CPU-s

One disc (R = 8, relaxed 40 time units) on a 40 × 30 Delaunay channel at h = 1
(:func:`femphase.domains.mesh.generation.delaunay_channel`, seed 1), carried 32 units by the
uniform flow u = 1 at the default (adaptive) scheme and phase dt = 0.25, 1, 2, 4, with each
advection of :mod:`femphase.domains.mesh.advection`:

* the explicit Runge–Kutta step (the batched solves' advection) of three stages with K = 0,
  1, 2, 3 Jacobi corrections of the lumped mass inverse (three stages and K = 2 are
  ``STAGES`` and ``MASS_CORRECTIONS``, the default), and of four stages (classical RK4) with
  K = 1, 2;
* the Galerkin–Padé step with exact per-window solves (``numerics.solver = "direct"``).

Reported: the displacement error (x travelled − 32)/32 and the change of elongation
(spurious stretching), and the CPU seconds of each carried run. The flow's exact
displacement is 32: the error is the advection's, in space and time. Writes
verification/results/mesh_advection.json and rewrites the ``mesh_advection`` block of
verification/README.md.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from femphase.analysis.shape import shape_observables  # noqa: E402
from femphase.config import Numerics  # noqa: E402
from femphase.domains.mesh import advection  # noqa: E402
from femphase.domains.mesh.domain import MeshDomain  # noqa: E402
from femphase.domains.mesh.generation import delaunay_channel, edge_for_spacing  # noqa: E402
from femphase.flows import python_flow  # noqa: E402
from femphase.model.parameters import ModelParameters  # noqa: E402
from femphase.state import discs_state  # noqa: E402
from femphase.timestepping.stepper import Stepper  # noqa: E402
from verification.readme import write_block  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
LENGTH, HEIGHT, DISTANCE = 40.0, 30.0, 32.0
STEPS = (0.25, 1.0, 2.0, 4.0)
#: name → (K, stages; None for Padé, numerics)
SCHEMES = {f"explicit, 3 stages, K = {k}": ((k, 3), Numerics()) for k in (0, 1, 2, 3)}
SCHEMES.update({f"explicit, 4 stages (RK4), K = {k}": ((k, 4), Numerics()) for k in (1, 2)})
SCHEMES["Galerkin–Padé (solver = \"direct\")"] = (None, Numerics(solver="direct"))


def carried(domain: MeshDomain, explicit: tuple[int, int] | None, numerics: Numerics, dt: float) -> dict:
    """The disc's displacement error and elongation change after DISTANCE units of u = 1."""
    params = ModelParameters()
    state = discs_state(domain, np.array([[10.0, HEIGHT / 2]]), np.array([8.0]), np.array([8.0]), 2.0,
                        domain.window_policy(numerics))
    relax = Stepper(domain, params, numerics, 1.0, None, state.radii)
    for _ in range(40):
        relax.step(state)
    start = shape_observables(state)
    uniform = python_flow(lambda x, y: (np.ones_like(x), np.zeros_like(y)))
    defaults = advection.MASS_CORRECTIONS, advection.STAGES
    try:
        if explicit is not None:
            advection.MASS_CORRECTIONS, advection.STAGES = explicit
        stepper = Stepper(domain, params, numerics, dt, uniform, state.radii)
        clock = time.process_time()
        for _ in range(round(DISTANCE / dt)):
            stepper.step(state)
        cpu = time.process_time() - clock
    finally:
        advection.MASS_CORRECTIONS, advection.STAGES = defaults
    end = shape_observables(state)
    travelled = (end.x[0] - start.x[0]) % LENGTH
    return {"dt": dt, "displacement_error": float((travelled - DISTANCE) / DISTANCE),
            "elongation_change": float(end.elongation[0] - start.elongation[0]), "cpu_s": cpu}


def block(results: dict) -> str:
    header = "| advection | " + " | ".join(f"dt = {dt:g}" for dt in STEPS) + " | CPU s (all dt) |"
    lines = [("`python verification/mesh_advection.py`: displacement error, elongation change of a disc "
              f"carried {DISTANCE:g} units by u = 1 on a Delaunay mesh at h = 1"), "", header,
             "|---|" + "---|" * (len(STEPS) + 1)]
    for name, rows in results.items():
        cells = " | ".join(f"{100 * row['displacement_error']:+.2f} %, {row['elongation_change']:+.4f}" for row in rows)
        lines.append(f"| {name} | {cells} | {sum(row['cpu_s'] for row in rows):.1f} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    domain = MeshDomain.from_mesh(*delaunay_channel(LENGTH, edge_for_spacing(1.0), lambda x: 0 * x,
                                                    lambda x: 0 * x + HEIGHT, seed=1))
    results = {}
    for name, (explicit, numerics) in SCHEMES.items():
        results[name] = [carried(domain, explicit, numerics, dt) for dt in STEPS]
        print(name, json.dumps(results[name]), flush=True)
    (RESULTS / "mesh_advection.json").write_text(json.dumps(results, indent=1) + "\n")
    text = block(results)
    print(text)
    write_block("mesh_advection", text, "Advection on meshes: a translating disc")


if __name__ == "__main__":
    main()
