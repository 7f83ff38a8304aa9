"""Step controllers for the adaptive scheme, compared at equal error (session 6's experiment).

    python benchmarks/controllers.py particle      # one particle from R/2, tests/test_adaptive.py's scene
    python benchmarks/controllers.py 1             # the random packing sheared at γ̇ = 1 (random_precision.py)
    python benchmarks/controllers.py lattice       # the lattice over one period (work_precision.py --schemes)

The default (``adaptive``: PI controller on the substep sizes dt/m, m = 2^k or 3·2^k) against two variants
registered here only, as schemes of this process:

* ``adaptive_i``: the elementary controller, h ← h · 0.9 (tolerance/error)^(1/2), which
  doubles a substep whenever 4 × the estimate is within 0.81 × the tolerance (PI, with its
  damped gain, doubles only below ~4 % of the tolerance and otherwise keeps its size);
* ``adaptive_epus``: error per unit step, the estimate scaled by (dt/4)/h (so the tolerance
  means the same at the starting size dt/4) with the elementary controller of order 1.

Each at several tolerances: accepted substeps and the error of r against a sav2 reference
(the particle: dt = 0.05, the largest error over the frames, relative to the largest r; the
packing: dt = 0.125, over 200 time units of shear, the largest and the median). Prints one
line per run; benchmarks/README.md ("Kept in session 6", the controller paragraphs) holds
the numbers of session 6.

``lattice`` (session 9): the default and the elementary controller at tolerances 3e-2 and
1e-2, each with the area term's rank-one mode explicit and implicit
(``numerics.area_implicit``), on ``work_precision.py --schemes``' lattice over one period:
CPU seconds and the r(t) and period errors in time against sav2 at dt = 0.25 (this run),
two processes at a time. benchmarks/README.md ("Session 9") holds the numbers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

from femphase.schemes import AdaptiveSAV2
from femphase.stepping import SCHEMES

TOLERANCES = {"adaptive": (3e-2, 1e-2, 3e-3), "adaptive_i": (1e-2, 3e-3, 1e-3),
              "adaptive_epus": (3e-2, 1e-2, 3e-3, 1e-3)}


@SCHEMES.register("adaptive_i")
class ElementaryController(AdaptiveSAV2):
    """The adaptive scheme with the elementary controller (no PI memory)."""

    name = "adaptive_i"
    K_I, K_P = 0.5, 0.0


@SCHEMES.register("adaptive_epus")
class ErrorPerUnitStep(AdaptiveSAV2):
    """The adaptive scheme controlling the error per unit step."""

    name = "adaptive_epus"
    K_I, K_P = 1.0, 0.0  # the scaled estimate is of order 1 in h

    def relax(self, phi, layout, time, radii, r, dt, **decays):
        new, r_next, estimate = super().relax(phi, layout, time, radii, r, dt, **decays)
        return new, r_next, estimate * (0.25 * self.stepper.dt) / dt


def particle() -> None:
    sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
    from test_adaptive import SubstepCounts, _sheared_particle

    reference = _sheared_particle("sav2", 0.05).series("elongation")[::200, 0]
    for scheme, tolerances in TOLERANCES.items():
        for tolerance in tolerances:
            counts = SubstepCounts()
            r = _sheared_particle(scheme, 10.0, tolerance, [counts]).series("elongation")[:, 0]
            print(f"particle {scheme} tolerance_t {tolerance:g}: {sum(int(c[0]) for c in counts.per_step)} substeps, "
                  f"largest r error {np.max(np.abs(r - reference)) / np.max(reference):.2e}", flush=True)


def packing(rate: float) -> None:
    import random_precision

    scene, _, relaxed, _ = common.relaxed_random_packing()
    reference = random_precision.shear(scene, relaxed, rate, 200.0, random_precision.REFERENCE_DT, scheme="sav2")
    for scheme, tolerances in TOLERANCES.items():
        for tolerance in tolerances:
            run = random_precision.shear(scene, relaxed, rate, 200.0, random_precision.FRAME, scheme=scheme,
                                         tolerance_t=tolerance)
            error = random_precision.errors(run, reference)
            print(f"random packing γ̇ = {rate:g} {scheme} tolerance_t {tolerance:g}: {run['substeps']} substeps "
                  f"({run['rejected']} rejected), {run['seconds']:.1f} CPU s, r error largest {error['max']:.2e}, "
                  f"median {error['median']:.2e}", flush=True)


def lattice() -> None:
    from concurrent.futures import ProcessPoolExecutor

    import work_precision

    Point = work_precision.Point
    points = [Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"})] + [
        Point("lattice", "fem", 1.0, work_precision.FRAME, {"scheme": scheme, "tolerance_t": tolerance,
                                                            "area_implicit": implicit})
        for scheme in ("adaptive", "adaptive_i") for tolerance in (3e-2, 1e-2) for implicit in (False, True)]
    with ProcessPoolExecutor(2) as pool:  # forked: the workers know the schemes registered here
        reference, *runs = pool.map(work_precision.run, points)
    for run in runs:
        errors = work_precision.lattice_errors(run, reference.result)
        print(f"lattice {run.label}: {run.seconds:.1f} CPU s, r(t) error {errors['elongation']:.2%}, "
              f"period error {errors['period']:.3%}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("problem", help='"particle", "lattice", or a shear rate for the random packing')
    args = parser.parse_args()
    if args.problem == "particle":
        particle()
    elif args.problem == "lattice":
        lattice()
    else:
        packing(float(args.problem))


if __name__ == "__main__":
    main()
