"""Single-precision flow steps on a mesh against double: what they change and save.

examples/straight_mesh.toml (N = 100, seed 1, dt = 10, default adaptive scheme) relaxed for
``--relax`` time units, then ``--flow`` time units of its Stokes flow (U = 0.1), once per
variant, each in its own child process:

* ``double``: ``numerics.precision = "double"`` (the reference);
* ``mixed``: the default, flow steps on a float32 working copy (batched CG solves and
  explicit advection on float32 block-diagonal matrices);
* ``dt_2.5``: the default with the flow phase's dt = 2.5 (substeps 2.5 instead of 3.33): a
  lower bound on the default's time error, the scale the rounding is set against.

For each: CG iterations and CPU seconds per phase (the relaxation computes in double in
every variant), and against ``double`` the largest difference in φ, in a centroid and in an
area (relative) at the end. Differences do not depend on the machine's load; CPU seconds do
(one run per variant, one after another: same-run ratios of whole runs are
``benchmarks/protocol.py --old``'s).

    python benchmarks/mesh_precision.py [--relax 400] [--flow 800]
"""

from __future__ import annotations

from pathlib import Path

import common  # pins BLAS threads (for the children too); straight_mesh_variant, differences

RESULT = Path(__file__).parent / "results" / "mesh_precision.json"
VARIANTS = ("double", "mixed", "dt_2.5")


def child(variant: str, relax: float, flow: float, output: Path) -> dict:
    """Run ``variant`` in this process; its fields, centroids and areas go to ``output`` (.npz)."""
    precision = "double" if variant == "double" else "mixed"
    return common.straight_mesh_variant(variant, relax, flow, output, 2.5 if variant == "dt_2.5" else 10.0,
                                        (f'numerics.precision="{precision}"',))


def main() -> None:
    runs = common.variant_main(__file__, __doc__, VARIANTS, 800.0, RESULT, child, "against_double")
    if runs is None:
        return
    common.print_differences(runs, "against_double", lambda run: (
        f"flow CPU {run['cpu_s'][1]:.2f} s (double {runs['double']['cpu_s'][1]:.2f})"))


if __name__ == "__main__":
    main()
