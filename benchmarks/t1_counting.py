"""How often the T1 counter must look, and what looking costs (``output.t1_interval``).

    python benchmarks/t1_counting.py

On the random packing of the paper's Fig. 1a (``examples/random.toml``, seed 1, relaxed at the
default scheme), sheared at γ̇ = 1 (the highest rate of the figure, where T1s are most
frequent):

* **convergence**: 3000 time units of shear at outer step 2.5, every step its own stepper
  call (``numerics.merged_steps = 1``: a tracker's ``after_step`` runs after each call, and
  calls of the default 8 steps made every look 20 apart); after the first 500, the
  centroids after every step are counted with :func:`femphase.analysis.lattice.t1_event_times`
  from every k-th step, giving the T1 rate against the spacing of the looks (2.5 … 400; 400
  is the frame interval of the paper's protocol);
* **cost**: CPU ms per time unit of shear at the default outer step 10, with the "order"
  observable's counter looking every ``output.t1_interval`` (the default) and only at the
  frames (every 400), in alternating blocks of ``BLOCK`` time units, at γ̇ = 1 and 0.0161.

Writes ``results/t1_counting.json`` and prints markdown tables (benchmarks/README.md,
"T1 counting").
"""

from __future__ import annotations

import copy
import json
import time
from dataclasses import replace
from pathlib import Path

import common
import numpy as np

from femphase.analysis.lattice import t1_event_times
from femphase.scene import Output
from femphase.run.simulation import Simulation, Tracker

RESULTS = Path(__file__).parent / "results"
STRIDES = (1, 2, 4, 8, 16, 32, 64, 160)
BLOCK, BLOCKS = 400.0, 5


def shear_scene(scene, rate: float, duration: float, dt: float, t1_interval: float, merged_steps: int | None = None):
    phase = replace(scene.phases[1], dt=dt, duration=duration, frame_interval=min(400.0, duration),
                    flow={**scene.phases[1].flow, "rate": rate})
    numerics = scene.numerics if merged_steps is None else replace(scene.numerics, merged_steps=merged_steps)
    return replace(scene, phases=(phase,), numerics=numerics,
                   output=replace(scene.output, t1_interval=t1_interval, fields=False))


def fresh_copy(relaxed):
    """The relaxed state as the start of a one-phase shear scene: time and step counts at 0,
    no scheme memory (substep level, counts)."""
    state = copy.deepcopy(relaxed)
    state.time, state.step, state.phase, state.phase_step = 0.0, 0, 0, 0
    state.memory.clear()
    return state


class CentroidsAfterSteps(Tracker):
    def __init__(self, skip: float) -> None:
        self.skip, self.times, self.centroids = skip, [], []

    def after_step(self, state) -> None:
        if state.time >= self.skip:
            self.times.append(state.time)
            self.centroids.append(state.domain.centroids(*state.flat()))


class NeedsOrder(Tracker):
    needs = frozenset({"shape", "order"})


def convergence(scene, relaxed) -> list[dict]:
    dt = 2.5
    state = fresh_copy(relaxed)
    tracker = CentroidsAfterSteps(skip=500.0)
    Simulation(shear_scene(scene, 1.0, 3000.0, dt, 1e9, merged_steps=1)).run(state, [tracker], initial_frame=False)
    times = np.array(tracker.times)
    rows = []
    for stride in STRIDES:
        frames = np.arange(0, times.size, stride)
        events = t1_event_times([tracker.centroids[k] for k in frames], times[frames], scene.domain.period).size
        rows.append({"spacing": stride * dt,
                     "rate_per_1000": 1000.0 * events / (len(relaxed.radii) * (times[frames[-1]] - times[frames[0]]))})
    return rows


def cost(scene, relaxed, rate: float) -> dict:
    looks = f"looks every {Output().t1_interval:g}"
    seconds = {looks: [], "frames only": []}
    for _ in range(BLOCKS):
        for label, interval in ((looks, Output().t1_interval), ("frames only", 1e9)):
            state = fresh_copy(relaxed)
            simulation = Simulation(shear_scene(scene, rate, BLOCK, 10.0, interval))
            started = time.process_time()
            simulation.run(state, [NeedsOrder()], initial_frame=False)
            seconds[label].append(time.process_time() - started)
    ms = {label: 1e3 * float(np.median(values)) / BLOCK for label, values in seconds.items()}
    return {"rate": rate, "looks": looks, "ms_per_time_unit": ms, "ratio": ms[looks] / ms["frames only"]}


def main() -> None:
    scene, _, relaxed, _ = common.relaxed_random_packing()
    result = {"convergence": convergence(scene, relaxed), "cost": [cost(scene, relaxed, r) for r in (1.0, 0.0161)],
              "command": "python benchmarks/t1_counting.py"}
    (RESULTS / "t1_counting.json").write_text(json.dumps(result, indent=1) + "\n")
    print("| spacing of the looks | T1 per particle per 1000 t (γ̇ = 1) |\n|---|---|")
    for row in result["convergence"]:
        print(f"| {row['spacing']:g} | {row['rate_per_1000']:.2f} |")
    print(f"\n| γ̇ | ms per time unit, {result['cost'][0]['looks']} | frames only | ratio |\n|---|---|---|---|")
    for row in result["cost"]:
        ms = row["ms_per_time_unit"]
        print(f"| {row['rate']:g} | {ms[row['looks']]:.2f} | {ms['frames only']:.2f} | {row['ratio']:.3f} |")


if __name__ == "__main__":
    import argparse

    argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter).parse_args()
    main()
