"""What the batched CG's tolerances cost and change on a mesh: the predictor's looser solve,
and the other solves' tolerance.

examples/straight_mesh.toml (N = 100, seed 1, dt = 10, default adaptive scheme) relaxed for
``--relax`` time units, then ``--flow`` time units of its Stokes flow (U = 0.1), once per
variant, each in its own child process:

* ``exact``: every batched solve to 1e-10 (the reference);
* ``default``: the window solves at ``Numerics.KRYLOV_FRACTION`` of the substep's tolerance
  (``krylov_tolerance``), the predictor's at ``Numerics.PREDICTOR_KRYLOV_FRACTION`` of it
  (``predictor_krylov_tolerance``);
* ``tight_predictor``: the predictor's solve at 1e-5 of the substep's tolerance (1e-6 under
  flow at the default, the midpoint step's tolerance before decision record 0024);
* ``solves_1e-4``, ``solves_1e-2``: the default with every batched solve but the predictor's
  (the midpoint step's, the relaxation's) at ``Numerics.KRYLOV_FRACTION`` = 1e-4 and 1e-2
  of the substep's tolerance instead of 1e-3 (relative residuals 1e-5 and 1e-3 under flow
  at the default; docs/decisions/0029-mesh-solves-at-1e-3.md);
* ``dt_2.5``: the default with the flow phase's dt = 2.5 (substeps 2.5 instead of 3.33): a
  lower bound on the default's time error, the scale the solves' errors are set against.

For each: CG iterations and CPU seconds per phase, and against ``exact`` the largest
difference in φ, in a centroid and in an area (relative) at the end. Iterations and
differences do not depend on the machine's load; CPU seconds do (one run per variant).

    python benchmarks/krylov_tolerance.py [--relax 400] [--flow 1200]
"""

from __future__ import annotations

from pathlib import Path

import common  # pins BLAS threads (for the children too); run_phases, differences

RESULT = Path(__file__).parent / "results" / "krylov_tolerance.json"
VARIANTS = ("exact", "default", "tight_predictor", "solves_1e-4", "solves_1e-2", "dt_2.5")


def child(variant: str, relax: float, flow: float, output: Path) -> dict:
    """Run ``variant`` in this process; its fields, centroids and areas go to ``output`` (.npz)."""
    from femphase.config import Numerics

    if variant == "exact":
        Numerics.KRYLOV_FRACTION = Numerics.PREDICTOR_KRYLOV_FRACTION = 1e-9  # → tolerance, 1e-10
    elif variant == "tight_predictor":
        Numerics.PREDICTOR_KRYLOV_FRACTION = 1e-5
    elif variant.startswith("solves_"):
        Numerics.KRYLOV_FRACTION = float(variant.removeprefix("solves_"))
    return common.straight_mesh_variant(variant, relax, flow, output, 2.5 if variant == "dt_2.5" else 10.0)


def main() -> None:
    runs = common.variant_main(__file__, __doc__, VARIANTS, 1200.0, RESULT, child, "against_exact")
    if runs is None:
        return
    common.print_differences(runs, "against_exact", lambda run: f"CG iterations {run['cg_iterations']}")


if __name__ == "__main__":
    main()
