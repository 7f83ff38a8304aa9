"""A disc translating in uniform flow on a Delaunay mesh: the meshes' advection steps.

    python verification/mesh_advection.py        # ~10 CPU-s

One disc (R = 8, relaxed 40 time units) on a 40 × 30 Delaunay channel at h = 1
(:func:`femphase.domains.mesh.generation.delaunay_channel`, seed 1), carried 32 units by the
uniform flow u = 1 at the default (adaptive) scheme and phase dt = 0.25, 1, 2, 4, with each
advection of :mod:`femphase.domains.mesh.advection`:

* the explicit Taylor–Galerkin step (the batched solves' advection) with K = 1, 2, 3 Jacobi
  corrections of its lumped inverse (K = 2, ``MASS_CORRECTIONS``, the default);
* the explicit Runge–Kutta step (``numerics.mesh_advection = "runge-kutta"``) of three
  stages with K = 0, 1, 2, 3 (three stages are ``STAGES``), and of four stages (classical
  RK4) with K = 1, 2;
* the Galerkin–Padé step with exact per-window solves (``numerics.solver = "direct"``);

and by u = 3 at phase dt 1, 2, 4 (advections at Courant numbers 1.4–5.6), the default (the
semi-Lagrangian step of :mod:`femphase.domains.mesh.semi_lagrangian` from Courant number 2
on) against the explicit Galerkin step at every Courant number; and at u = 1, phase dt 1,
on the channel's Delaunay mesh at h = 0.5 under the default, the three-stage Runge–Kutta
step (K = 2) and Galerkin–Padé: how each error at h = 1 falls as h halves.

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
from femphase.domains.mesh import advection, semi_lagrangian  # noqa: E402
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
SCHEMES = {f"Taylor–Galerkin, K = {k}" + " (default)" * (k == 2): ((k, 3), Numerics()) for k in (1, 2, 3)}
SCHEMES.update({f"Runge–Kutta, 3 stages, K = {k}": ((k, 3), Numerics(mesh_advection="runge-kutta"))
                for k in (0, 1, 2, 3)})
SCHEMES.update({f"Runge–Kutta, 4 stages (RK4), K = {k}": ((k, 4), Numerics(mesh_advection="runge-kutta"))
                for k in (1, 2)})
SCHEMES["Galerkin–Padé (solver = \"direct\")"] = (None, Numerics(solver="direct"))
#: the fast disc: speed, phase dts, and name → the Courant number from which it advects semi-Lagrangian
FAST_SPEED, FAST_STEPS = 3.0, (1.0, 2.0, 4.0)
FAST_SCHEMES = {"default (semi-Lagrangian from Courant number 2)": semi_lagrangian.COURANT,
                "explicit Galerkin (Taylor–Galerkin, K = 2) at every Courant number": float("inf")}
#: the disc on a finer mesh: spacing, phase dts, and the schemes (names of SCHEMES)
FINE_SPACING, FINE_STEPS = 0.5, (1.0,)
FINE_SCHEMES = ("Taylor–Galerkin, K = 2 (default)", "Runge–Kutta, 3 stages, K = 2",
                "Galerkin–Padé (solver = \"direct\")")


def carried(domain: MeshDomain, explicit: tuple[int, int] | None, numerics: Numerics, dt: float,
            speed: float = 1.0) -> dict:
    """The disc's displacement error and elongation change after the whole steps nearest to
    DISTANCE units of u = ``speed``."""
    params = ModelParameters()
    state = discs_state(domain, np.array([[10.0, HEIGHT / 2]]), np.array([8.0]), np.array([8.0]), 2.0,
                        domain.window_policy(numerics))
    relax = Stepper(domain, params, numerics, 1.0, None, state.radii)
    for _ in range(40):
        relax.step(state)
    start = shape_observables(state)
    uniform = python_flow(lambda x, y: (np.full_like(x, speed), np.zeros_like(y)))
    defaults = advection.MASS_CORRECTIONS, advection.STAGES
    try:
        if explicit is not None:
            advection.MASS_CORRECTIONS, advection.STAGES = explicit
        stepper = Stepper(domain, params, numerics, dt, uniform, state.radii)
        clock = time.process_time()
        steps = round(DISTANCE / (speed * dt))
        for _ in range(steps):
            stepper.step(state)
        cpu = time.process_time() - clock
    finally:
        advection.MASS_CORRECTIONS, advection.STAGES = defaults
    end = shape_observables(state)
    travelled, distance = (end.x[0] - start.x[0]) % LENGTH, speed * dt * steps
    return {"dt": dt, "speed": speed, "displacement_error": float((travelled - distance) / distance),
            "elongation_change": float(end.elongation[0] - start.elongation[0]), "cpu_s": cpu}


def table(results: dict, steps: tuple[float, ...]) -> list[str]:
    lines = ["| advection | " + " | ".join(f"dt = {dt:g}" for dt in steps) + " | CPU s (all dt) |",
             "|---|" + "---|" * (len(steps) + 1)]
    for name, rows in results.items():
        cells = " | ".join(f"{100 * row['displacement_error']:+.2f} %, {row['elongation_change']:+.4f}" for row in rows)
        lines.append(f"| {name} | {cells} | {sum(row['cpu_s'] for row in rows):.1f} |")
    return lines


def block(results: dict, fast: dict, fine: dict) -> str:
    lines = [("`python verification/mesh_advection.py`: displacement error, elongation change of a disc "
              f"carried {DISTANCE:g} units by u = 1 on a Delaunay mesh at h = 1"), "", *table(results, STEPS), "",
             f"The same disc carried by u = {FAST_SPEED:g} (the whole steps nearest to {DISTANCE:g} units):", "",
             *table(fast, FAST_STEPS), "",
             f"The same disc at u = 1 on the channel's Delaunay mesh at h = {FINE_SPACING:g} (how each error at "
             "h = 1 falls as h halves):", "", *table(fine, FINE_STEPS)]
    return "\n".join(lines) + "\n"


def fast_disc(domain: MeshDomain) -> dict:
    """The disc carried by u = FAST_SPEED under each of FAST_SCHEMES."""
    results, default = {}, semi_lagrangian.COURANT
    try:
        for name, courant in FAST_SCHEMES.items():
            semi_lagrangian.COURANT = courant
            results[name] = [carried(domain, None, Numerics(), dt, FAST_SPEED) for dt in FAST_STEPS]
            print(name, json.dumps(results[name]), flush=True)
    finally:
        semi_lagrangian.COURANT = default
    return results


def channel(spacing: float) -> MeshDomain:
    return MeshDomain.from_mesh(*delaunay_channel(LENGTH, edge_for_spacing(spacing), lambda x: 0 * x,
                                                  lambda x: 0 * x + HEIGHT, seed=1))


def main() -> None:
    domain = channel(1.0)
    results = {}
    for name, (explicit, numerics) in SCHEMES.items():
        results[name] = [carried(domain, explicit, numerics, dt) for dt in STEPS]
        print(name, json.dumps(results[name]), flush=True)
    fast = fast_disc(domain)
    fine_domain, fine = channel(FINE_SPACING), {}
    for name in FINE_SCHEMES:
        explicit, numerics = SCHEMES[name]
        fine[name] = [carried(fine_domain, explicit, numerics, dt) for dt in FINE_STEPS]
        print(name, f"h = {FINE_SPACING:g}", json.dumps(fine[name]), flush=True)
    (RESULTS / "mesh_advection.json").write_text(json.dumps({**results, "fast": fast, "fine": fine}, indent=1) + "\n")
    text = block(results, fast, fine)
    print(text)
    write_block("mesh_advection", text, "Advection on meshes: a translating disc")


if __name__ == "__main__":
    import argparse

    # no options: an argument parser so that --help describes the run instead of starting it
    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
