"""An oscillating shear on a mesh: its advection operators scaled, against built at every step.

examples/straight_mesh.toml (N = 100, seed 1, dt = 10, default adaptive scheme) relaxed for
``--relax`` time units, then ``--flow`` time units of shear, once per variant, each in its
own child process:

* ``assembled``: the oscillating shear u = γ̇ sin(ωt) y/Ly (γ̇ = 0.1, ω = 2π/200) given as
  u(y, t) alone, so that the Galerkin advection assembles C from the step's mean velocity,
  and estimates its ω, at every step (the reference);
* ``scaled``: the same flow as the scene builds it, u = f(t) w(y) of fixed direction field:
  C and ω are w's, built once, times f's mean over each step (the default);
* ``steady``: the steady shear u = γ̇ y/Ly, the cost of a flow that does not change.

For each: CPU seconds per phase; against ``assembled`` the largest difference in φ, in a
centroid and in an area (relative) at the end (for ``steady`` a different flow's: listed,
not a discrepancy). Differences do not depend on the machine's load; CPU seconds do (one
run per variant, one after another).

    python benchmarks/mesh_unsteady.py [--relax 400] [--flow 400]
"""

from __future__ import annotations

import math
from pathlib import Path

import common  # pins BLAS threads (for the children too); straight_mesh_variant, differences

RESULT = Path(__file__).parent / "results" / "mesh_unsteady.json"
VARIANTS = ("assembled", "scaled", "steady")
RATE, FREQUENCY = 0.1, 2 * math.pi / 200.0


def child(variant: str, relax: float, flow: float, output: Path) -> dict:
    """Run ``variant`` in this process; its fields, centroids and areas go to ``output`` (.npz)."""
    if variant == "assembled":  # the flow without its amplitude and profile: C built at every step
        from dataclasses import replace

        from femphase import flows

        separable = flows.separable_row_flow
        flows.separable_row_flow = lambda *arguments, **keywords: replace(
            separable(*arguments, **keywords), amplitude=None, profile=None)
    table = (f'{{type = "shear", rate = {RATE}}}' if variant == "steady" else
             f'{{type = "oscillating_shear", rate = {RATE}, frequency = {FREQUENCY!r}}}')
    return common.straight_mesh_variant(variant, relax, flow, output, sets=(f"phases.1.flow={table}",))


def main() -> None:
    runs = common.variant_main(__file__, __doc__, VARIANTS, 400.0, RESULT, child, "against_assembled")
    if runs is None:
        return
    reference = runs["assembled"]["cpu_s"][1]
    for variant, run in runs.items():
        line = f"{variant}: flow CPU {run['cpu_s'][1]:.2f} s ({run['cpu_s'][1] / reference:.3f}× assembled's)"
        if variant != "assembled":
            d = run["against_assembled"]
            line += (f"; against assembled{' (another flow)' if variant == 'steady' else ''}: φ {d['max_phi']:.2g}, "
                     f"centroid {d['max_centroid']:.2g}, area {d['max_relative_area']:.2g}")
        print(line)


if __name__ == "__main__":
    main()
