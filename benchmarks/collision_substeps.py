"""Does the substep follow a collision? Substeps per frame through two discs' collision.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 NUMBA_NUM_THREADS=1 python benchmarks/collision_substeps.py

``tolerance.py``'s collision (two discs of R = 8 passing each other in a shear at κ × 10, the
whole 60 × 40 channel) run for 300 time units, through the approach (apart until t ≈ 30),
the contact (repulsion energy peaking at t ≈ 130) and the separation (apart again from
t ≈ 260), with the embedded and the step-doubling estimate (``numerics.estimate``) at
``tolerance_t`` = 1e-4 and 1e-5: the accepted substeps in every 10 time units, beside the
repulsion energy at the frames. A controller that the estimate drives takes small substeps
during the contact and large ones while the discs are apart. Writes
results/collision_substeps.json and its README section.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import common  # pins BLAS threads before numpy loads
import tolerance

from femphase.run.simulation import Simulation, Tracker
from femphase.run.trackers import FrameRecorder

RESULT = Path(__file__).resolve().parent / "results" / "collision_substeps.json"
DURATION = 300.0
RUNS = (("embedded", 1e-4), ("doubling", 1e-4), ("embedded", 1e-5), ("doubling", 1e-5))


class SubstepsPerFrame(Tracker):
    """The adaptive scheme's accepted substeps between consecutive frames."""

    def __init__(self) -> None:
        self.counts, self._last = [], 0

    def frame(self, frame) -> None:
        counts = frame.state.memory.get("adaptive_phase_counts")
        accepted = 0 if counts is None else int(counts[-1, 0])
        self.counts.append(accepted - self._last)
        self._last = accepted


def run(estimate: str, tol: float) -> dict:
    scene = tolerance.collision_scene({"tolerance_t": tol, "estimate": estimate}, 10.0)
    scene = replace(scene, phases=(replace(scene.phases[0], duration=DURATION),))
    substeps, recorder = SubstepsPerFrame(), FrameRecorder()
    Simulation(scene).run(scene.initial_state(), [substeps, recorder])
    return {"estimate": estimate, "tolerance_t": tol, "times": recorder.times[1:].tolist(),
            "substeps": substeps.counts[1:], "repulsion": recorder.series("repulsion", "global")[1:].tolist()}


def report(result: dict) -> str:
    runs = result["runs"]
    lines = ["| t | repulsion energy | " + " | ".join(f"{r['estimate']} {r['tolerance_t']:g}" for r in runs) + " |",
             "|---" * (2 + len(runs)) + "|"]
    for k, time in enumerate(runs[0]["times"]):
        lines.append(f"| {time - 10:g}–{time:g} | {runs[0]['repulsion'][k]:.3f} | "
                     + " | ".join(str(r["substeps"][k]) for r in runs) + " |")
    totals = " | ".join(str(sum(r["substeps"])) for r in runs)
    return ("Accepted substeps per 10 time units (repulsion energy at the interval's end):\n\n"
            + "\n".join(lines) + f"\n| total | | {totals} |\n\nCommand: `{result['command']}`.")


def main() -> None:
    result = {"runs": [run(*spec) for spec in RUNS], "command": "python benchmarks/collision_substeps.py"}
    RESULT.write_text(json.dumps(result, indent=1) + "\n")
    common.update_readme("collision_substeps", report(result))
    print(report(result))


if __name__ == "__main__":
    main()
