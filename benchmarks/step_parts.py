"""Where the default step's time goes: wall time of its parts, on the lattice under shear.

    python benchmarks/step_parts.py [--steps 100] [--random-rate R]

``step_time.py``'s set-up (the N = 100 lattice at h = 1, relaxed 100 time units by the
first-order scheme, then sheared at γ̇ = 0.1487 with the default scheme, outer step 10)
runs ``--steps`` outer steps with a timer around each of these methods (a part's time
includes the parts it calls: a refit includes its misfit checks and layout moves):
``Stepper.solve`` (the tensor solves), ``Stepper.refit`` (window refits),
``WindowPolicy.misfits`` (their checks), ``RowShift.advect`` (advection),
``GridDomain.layout`` (layouts moved or built, by refits and advections) and
``RelaxedSAV2.decay`` (the repulsion's decay). Prints each part's share of the run, its
ms per call and its calls. Less overhead than a sampling profiler on calls this short, and
the same numbers from run to run within the machine's noise.

``--random-rate R``: the random packing instead (``examples/random.toml``, seed 1, relaxed
by the default scheme as in ``step_time.py --random-rates``), sheared at γ̇ = R with its
scene's outer step. Its windows come in more shapes than the lattice's, and every part
above loops over the shapes (groups): the mean number of groups is printed too.

``--scaling-n N``: ``scaling.py``'s scene of N particles instead (a channel grown in both
directions, relaxed as there, the default scheme at its outer step): with the cost per
position and substep printed, ``--scaling-n 100`` against ``--scaling-n 1600`` tells how the
step grows with N without the exponent's sensitivity to one size's noise.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from dataclasses import replace

import common  # pins BLAS threads before numpy loads
import numpy as np

from femphase.domains.grid.advection import RowShift
from femphase.domains.grid.domain import GridDomain
from femphase.timestepping.sav2 import RelaxedSAV2
from femphase.timestepping.stepper import Stepper
from femphase.domains.grid.windows import WindowPolicy
from step_time import relaxed_lattice, shear_stepper
from work_precision import FRAME

PARTS = {"solves": (Stepper, "solve"), "refits": (Stepper, "refit"), "misfit checks": (WindowPolicy, "misfits"),
         "advection": (RowShift, "advect"), "layouts": (GridDomain, "layout"), "decay": (RelaxedSAV2, "decay")}


def timed(seconds: dict, calls: dict, name: str, method):
    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds[name] += time.perf_counter() - started
            calls[name] += 1
    return wrapper


def random_stepper(rate: float):
    """(stepper, state, outer step) of the relaxed random packing sheared at ``rate``, after
    one set-up step."""
    scene, simulation, state, _ = common.relaxed_random_packing()
    stepper, phase = common.random_shear_stepper(scene, simulation, state, rate)
    stepper.step(state)
    return stepper, state, phase.dt


def scaling_stepper(n: int):
    """(stepper, state, outer step) of scaling.py's N-particle scene, relaxed as there, the
    default scheme after one set-up step."""
    from scaling import sheared_stepper, square_channel

    scene = square_channel(n)
    state, _, simulation = sheared_stepper(scene, scheme="euler")
    phase = replace(scene.phases[0], dt=FRAME)
    stepper = Stepper(simulation.domain, scene.model, scene.numerics, FRAME, scene.flow(phase), state.radii)
    stepper.step(state)
    return stepper, state, FRAME


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=100)
    scene = parser.add_mutually_exclusive_group()
    scene.add_argument("--random-rate", type=float, default=None,
                       help="shear the relaxed random packing at this rate instead of the lattice")
    scene.add_argument("--scaling-n", type=int, default=None,
                       help="scaling.py's scene of this many particles instead of the lattice")
    args = parser.parse_args()
    if args.random_rate is not None:
        stepper, state, outer = random_stepper(args.random_rate)
    elif args.scaling_n is not None:
        stepper, state, outer = scaling_stepper(args.scaling_n)
    else:
        simulation, scene, state = relaxed_lattice()
        stepper, outer = shear_stepper(simulation, scene, state, FRAME), FRAME
    seconds, calls = defaultdict(float), defaultdict(int)
    for name, (owner, method) in PARTS.items():
        setattr(owner, method, timed(seconds, calls, name, getattr(owner, method)))
    groups, counted = [], state.memory["adaptive_counts"].copy()
    started = time.perf_counter()
    for _ in range(args.steps):
        stepper.step(state)
        groups.append(len(state.flat()[0].groups))
    total = time.perf_counter() - started
    counts = state.memory["adaptive_counts"] - counted
    print(f"{args.steps} outer steps of {outer:g}: {1e3 * total / (args.steps * outer):.2f} ms per time unit, "
          f"{1e3 * total / max(int(counts[0]), 1):.2f} ms per accepted substep ({int(counts[0])} accepted, "
          f"{int(counts[1])} rejected), {np.mean(groups):.1f} window shapes (groups), "
          f"{1e9 * total / max(int(counts[0]), 1) / state.flat()[1].size:.1f} ns per position and substep")
    print("| part | share | ms per call | calls |\n|---|---|---|---|")
    for name in PARTS:
        print(f"| {name} | {100 * seconds[name] / total:.0f} % | {1e3 * seconds[name] / max(calls[name], 1):.3f} | "
              f"{calls[name]} |")


if __name__ == "__main__":
    main()
