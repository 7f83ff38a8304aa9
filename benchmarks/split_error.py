"""Where sav2's error at substep 5 comes from, on the lattice over one period (session 10).

    python benchmarks/split_error.py

Session 9 measured sav2 at a fixed dt = 5 with the area term's rank-one mode implicit
(``numerics.area_implicit``) at 3.2 % r(t) and 0.37 % period error in time (issue 12 allows
2 % and 0.3 %), and put that on the error of the repulsion split, which the adaptive
estimate does not contain. This separates the candidates, on ``work_precision.py
--schemes``' lattice protocol (relax 300, shear 3600 at γ̇ = 0.1487, a frame every 10), all
at dt = 5 with the area mode implicit, errors in time against sav2 at dt = 0.25 (this run):

* ``split``: sav2 as it is (the repulsion's decay over dt/2, the midpoint step of the other
  terms, the decay over dt/2);
* ``split, decay in 8 substeps``: each half-decay integrated by 8 exponential-midpoint
  steps (``sav2_fine_decay``, registered here only): the decay's own integration error
  removed, the splitting left;
* ``unsplit``: the repulsion inside the explicit midpoint step (``repulsion_split = false``);
* ``relaxation in 8 substeps``: the whole relaxation (decays and midpoint steps) of each
  step in 8 substeps of dt/8 (``sav2_fine_relaxation``, registered here only) between the
  two half-advections of dt/2: the relaxation's own error removed, the splitting of
  advection and relaxation left (session 11);

and, for the step between, sav2 as it is (area mode explicit, as in the default) at
dt = 10/3 and 2.5, the adaptive scheme's substeps at its default tolerance after and before
session 10.

Besides the r(t) and period errors (as in ``work_precision.py``), the signed error of the
mean elongation at t = 1100 and 1300, in the first slow stretch before the first T1 event
(r grows from 0.13 to 0.98 there), relative to the largest r: a bias that builds up there
is a local error accumulating with one sign, not the T1 events' timing.
Prints a table; benchmarks/README.md ("Session 10", "Session 11") holds the numbers: the
relaxation in 8 substeps removes most of the stretch's bias (+1.29 → +0.39 %) but leaves a
4 % r(t) error, the splitting of advection and relaxation at 5 alone.
"""

from __future__ import annotations

import common  # noqa: F401  (pins BLAS threads before numpy loads)
import numpy as np

import work_precision as wp
from femphase.schemes import RelaxedSAV2
from femphase.stepping import SCHEMES

STRETCH_TIMES = (1100.0, 1300.0)
DECAY_SUBSTEPS = 8


@SCHEMES.register("sav2_fine_decay")
class FineDecay(RelaxedSAV2):
    """sav2 with every decay of the split in DECAY_SUBSTEPS exponential-midpoint steps."""

    name = "sav2_fine_decay"

    def decay(self, phi, layout, radii, dt):
        for _ in range(DECAY_SUBSTEPS):
            phi = super().decay(phi, layout, radii, dt / DECAY_SUBSTEPS)
        return phi


@SCHEMES.register("sav2_fine_relaxation")
class FineRelaxation(RelaxedSAV2):
    """sav2 with every relaxation step in DECAY_SUBSTEPS steps, the advection split unchanged."""

    name = "sav2_fine_relaxation"

    def relax(self, phi, layout, time, radii, r, dt, decay_before=None, decay_after=None):
        substep, largest = dt / DECAY_SUBSTEPS, 0.0
        for k in range(DECAY_SUBSTEPS):
            phi, r, estimate = super().relax(phi, layout, time + k * substep, radii, r, substep)
            largest = max(largest, estimate)
        return phi, r, largest


def main() -> None:
    reference = wp.run(wp.Point("lattice", "fem", 1.0, 0.25, {"scheme": "sav2"}))
    implicit = {"area_implicit": True}
    runs = [("split, area mode implicit", 5.0, {"scheme": "sav2", **implicit}),
            (f"split, decay in {DECAY_SUBSTEPS} substeps, area mode implicit", 5.0,
             {"scheme": "sav2_fine_decay", **implicit}),
            ("unsplit, area mode implicit", 5.0, {"scheme": "sav2", "repulsion_split": False, **implicit}),
            (f"relaxation in {DECAY_SUBSTEPS} substeps, area mode implicit", 5.0,
             {"scheme": "sav2_fine_relaxation", **implicit}),
            ("split", 10.0 / 3.0, {"scheme": "sav2"}),
            ("split", 2.5, {"scheme": "sav2"})]
    times = np.array(reference.result["times"])
    r_ref = np.array(reference.result["mean_elongation"])
    print("| sav2 | dt | CPU s | r(t), in time | period, in time | "
          + " | ".join(f"r error at t = {t:g}" for t in STRETCH_TIMES) + " |")
    print("|---|---|---|---|---|" + "---|" * len(STRETCH_TIMES))
    for label, dt, options in runs:
        point = wp.run(wp.Point("lattice", "fem", 1.0, dt, options))
        errors = wp.lattice_errors(point, reference.result)
        signed = (np.array(point.result["mean_elongation"]) - r_ref) / np.max(np.abs(r_ref))
        at = [signed[np.argmin(np.abs(times - t))] for t in STRETCH_TIMES]
        print(f"| {label} | {dt:.3g} | {point.seconds:.1f} | {100 * errors['elongation']:.2f} % | {100 * errors['period']:.3f} % | "
              + " | ".join(f"{100 * e:+.2f} %" for e in at) + " |", flush=True)


if __name__ == "__main__":
    main()
