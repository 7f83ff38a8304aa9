"""Where the default step's time goes: wall time of its parts, on the lattice under shear.

    python benchmarks/step_parts.py [--steps 100]

``step_time.py``'s set-up (the N = 100 lattice at h = 1, relaxed 100 time units by the
first-order scheme, then sheared at γ̇ = 0.1487 with the default scheme, outer step 10)
runs ``--steps`` outer steps with a timer around each of these methods (a part's time
includes the parts it calls: a refit includes its misfit checks and layout moves):
``Stepper.solve`` (the tensor solves), ``Stepper.refit`` (window refits),
``WindowPolicy.misfits`` (their checks), ``RowShift.advect`` (advection),
``ChannelDomain.layout`` (layouts moved or built, by refits and advections) and
``RelaxedSAV2.decay`` (the repulsion's decay). Prints each part's share of the run, its
ms per call and its calls. Less overhead than a sampling profiler on calls this short, and
the same numbers from run to run within the machine's noise.
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict

import common  # noqa: F401  (pins BLAS threads before numpy loads)

from femphase.advection import RowShift
from femphase.channel import ChannelDomain
from femphase.schemes import RelaxedSAV2
from femphase.stepping import Stepper
from femphase.windows import WindowPolicy
from step_time import relaxed_lattice, shear_stepper
from work_precision import FRAME

PARTS = {"solves": (Stepper, "solve"), "refits": (Stepper, "refit"), "misfit checks": (WindowPolicy, "misfits"),
         "advection": (RowShift, "advect"), "layouts": (ChannelDomain, "layout"), "decay": (RelaxedSAV2, "decay")}


def timed(seconds: dict, calls: dict, name: str, method):
    def wrapper(*args, **kwargs):
        started = time.perf_counter()
        try:
            return method(*args, **kwargs)
        finally:
            seconds[name] += time.perf_counter() - started
            calls[name] += 1
    return wrapper


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=100)
    args = parser.parse_args()
    simulation, scene, state = relaxed_lattice()
    stepper = shear_stepper(simulation, scene, state, FRAME)
    seconds, calls = defaultdict(float), defaultdict(int)
    for name, (owner, method) in PARTS.items():
        setattr(owner, method, timed(seconds, calls, name, getattr(owner, method)))
    started = time.perf_counter()
    for _ in range(args.steps):
        stepper.step(state)
    total = time.perf_counter() - started
    counts = state.memory["adaptive_counts"]
    print(f"{args.steps} outer steps of {FRAME:g}: {1e3 * total / (args.steps * FRAME):.2f} ms per time unit, "
          f"{1e3 * total / max(int(counts[0]), 1):.2f} ms per accepted substep ({int(counts[0])} accepted, "
          f"{int(counts[1])} rejected, set-up step included)")
    print("| part | share | ms per call | calls |\n|---|---|---|---|")
    for name in PARTS:
        print(f"| {name} | {100 * seconds[name] / total:.0f} % | {1e3 * seconds[name] / max(calls[name], 1):.3f} | "
              f"{calls[name]} |")


if __name__ == "__main__":
    main()
