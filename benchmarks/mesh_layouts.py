"""How often a mesh builds a new layout, and what refitting boxes together changes.

examples/straight_mesh.toml (N = 100, seed 1, dt = 10, default adaptive scheme) relaxed for
``--relax`` time units, then ``--flow`` time units of its Stokes flow (U = 0.1), in calls of
two steps as ``femphase run`` makes them, once per variant, each in its own child process:

* ``room``: boxes leave room for the coming step's motion at every call's refit
  (``BoxPolicy.lookahead``), none at the substeps' refits, no early refits (the windows
  with a solver each, and the batched windows before ``BoxPolicy.early``);
* ``early_0``: no room for motion, no early refits;
* ``early_1``, ``early_2`` (the default), ``early_3``: no room for motion; when a box must
  be refitted, every box within 1, 2 or 3 spacings of a bound is refitted with it.

For each: new layouts and refits per phase, mean positions (window dofs summed), CPU
seconds per phase, and against ``room`` the largest difference in φ, in a centroid and in an
area (relative) at the end. Counts and differences do not depend on the machine's load; CPU
seconds do (one run per variant).

    python benchmarks/mesh_layouts.py [--relax 400] [--flow 800]
"""

from __future__ import annotations

import time
from pathlib import Path

import common  # pins BLAS threads (for the children too); save_end_state, differences
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULT = Path(__file__).parent / "results" / "mesh_layouts.json"
VARIANTS = ("room", "early_0", "early_1", "early_2", "early_3")


def child(variant: str, relax: float, flow: float, output: Path) -> dict:
    """Run ``variant`` in this process; its end state goes to ``output`` (.npz)."""
    from femphase.domains.mesh.boxes import BoxPolicy
    from femphase.domains.mesh.domain import MeshDomain
    from femphase.run.simulation import Simulation
    from femphase.scene import load_scene
    from femphase.timestepping.stepper import Stepper

    counts = {"layouts": 0, "refits": 0}
    build, refit = MeshDomain.layout, MeshDomain.refit

    def counted_layout(self, windows):
        last = self._last_layout.get("last")
        if last is None or last.windows != tuple(windows):
            counts["layouts"] += 1
        return build(self, windows)

    def counted_refit(self, *args):
        counts["refits"] += 1
        return refit(self, *args)

    MeshDomain.layout, MeshDomain.refit = counted_layout, counted_refit
    if variant == "room":
        BoxPolicy.EARLY_SPACINGS = 0.0

        def refit_with_room(self, layout, phi, time=None):
            motion = None if time is None else (lambda: self._motion(layout, phi, time))
            return self.domain.refit(layout, phi, self.policy, motion)

        Stepper.refit = refit_with_room
    else:
        BoxPolicy.EARLY_SPACINGS = float(variant.split("_")[1])
    scene = load_scene(ROOT / "examples" / "straight_mesh.toml", [
        "phases.0.dt=10.0", "phases.1.dt=10.0", f"phases.0.duration={relax}", f"phases.1.duration={flow}",
        "output.fields=false"])
    simulation = Simulation(scene)
    state = scene.initial_state()
    phases = []
    for phase in scene.phases:
        stepper = simulation.stepper(phase, state.radii)
        stepper.scheme.start_phase(state)
        counts.update(layouts=0, refits=0)
        positions = []
        started = time.process_time()
        for _ in range(phase.n_steps // common.EXAMPLE_CALL):
            stepper.step(state, common.EXAMPLE_CALL)
            positions.append(sum(field.size for field in state.fields))
        phases.append({"cpu_s": time.process_time() - started, **counts, "mean_positions": float(np.mean(positions))})
    common.save_end_state(state, stepper, output)
    return {"variant": variant, "phases": phases, "period": float(stepper.domain.period)}


def main() -> None:
    runs = common.variant_main(__file__, __doc__, VARIANTS, 800.0, RESULT, child, "against_room")
    if runs is None:
        return
    for variant in VARIANTS:
        relaxation, flowing = runs[variant]["phases"]
        d = runs[variant].get("against_room")
        print(f"{variant}: layouts {relaxation['layouts']} + {flowing['layouts']} of "
              f"{relaxation['refits']} + {flowing['refits']} refits, positions {flowing['mean_positions']:.0f}, "
              f"flow CPU {flowing['cpu_s']:.1f} s"
              + ("" if d is None else f"; against room: φ {d['max_phi']:.2g}, centroid {d['max_centroid']:.2g}, "
                                      f"area {d['max_relative_area']:.2g}"))


if __name__ == "__main__":
    main()
