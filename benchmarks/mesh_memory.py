"""Resident memory of a meshed run over time, with glibc's default allocator settings and
with large allocations served by mmap.

    python benchmarks/mesh_memory.py [--stokes-time 2000] [--allocator default] [--output NAME.json]

examples/obstacle_mesh.toml (95 particles around an obstacle, P1 on an unstructured mesh)
relaxed 200 time units, then driven by its Stokes flow for ``--stokes-time``; the resident
set (``/proc/self/statm``) and the bytes the domain's cache budget holds
(``domain.caches.used``, :mod:`femphase.caches`) every 100 time units, the process's peak
resident set (``ru_maxrss``: between the samples too), and the CPU seconds of the flow phase,
each configuration in its own process:

* ``default``: glibc's malloc as it comes. Its mmap threshold starts at 128 kB and rises to
  the size of any mmapped block freed (up to 32 MB), after which blocks of those sizes come
  from the heap, where freed ones leave holes.
* ``mmap above 128 kB``: ``MALLOC_MMAP_THRESHOLD_=131072 MALLOC_TRIM_THRESHOLD_=131072``
  in the environment (glibc's tunables; nothing in femphase changes): every block from
  128 kB up is mapped on its own and returned to the system when freed.

Memory is bounded by design: the windows' systems are solved all at once by CG on
block-diagonal matrices (femphase/fem/blocks.py), the advection applies such matrices
explicitly, and only the current layout's block maps are kept, so nothing grows with the
boxes met, and every cache draws on the domain's one byte budget (``numerics.cache_mib``);
the two configurations show that no allocator setting is needed for it.
Writes results/mesh_memory.json (``--output``: another name in results/); ``--allocator``
runs one configuration only (a long run of glibc as it comes: ``--allocator default``).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import common  # pins BLAS threads before numpy loads

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
SCENE = HERE.parent / "examples" / "obstacle_mesh.toml"
CONFIGS = {"default": {}, "mmap above 128 kB": {"MALLOC_MMAP_THRESHOLD_": "131072", "MALLOC_TRIM_THRESHOLD_": "131072"}}
RELAX, SAMPLE = 200.0, 100.0


def worker(stokes_time: float) -> None:
    import resource
    import time

    from femphase.run.trackers import memory_mib
    from femphase.scene import load_scene
    from femphase.run.simulation import Simulation, Tracker

    class Probe(Tracker):
        def __init__(self) -> None:
            self.samples, self.started = [], None

        def after_step(self, state) -> None:
            if abs(state.time / SAMPLE - round(state.time / SAMPLE)) < 1e-9:
                self.samples.append((state.time, memory_mib()[0], state.domain.caches.used / 2**20))
            if abs(state.time - RELAX) < 1e-9:
                self.started = time.process_time()

    scene = load_scene(SCENE, [f"phases.0.duration={RELAX}", f"phases.1.duration={stokes_time}"])
    probe = Probe()
    Simulation(scene).run(scene.initial_state(), [probe])
    # the samples see the resident set every 100 time units; the peak (Linux: KiB) sees it always
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"samples": probe.samples, "flow_cpu_seconds": time.process_time() - probe.started,
                      "peak_mib": peak}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--stokes-time", type=float, default=1000.0)
    parser.add_argument("--allocator", choices=list(CONFIGS), action="append",
                        help="a configuration to run (repeatable; default: all)")
    parser.add_argument("--output", default="mesh_memory.json", help="file name in benchmarks/results/")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        worker(args.stokes_time)
        return
    options = ([f"--stokes-time {args.stokes_time:g}"] if args.stokes_time != 1000.0 else []) + [
        f"--allocator {name!r}" for name in args.allocator or []] + (
        [f"--output {args.output}"] if args.output != "mesh_memory.json" else [])
    out = {"command": " ".join(["python benchmarks/mesh_memory.py", *options]),
           "scene": f"examples/obstacle_mesh.toml, relaxed {RELAX:g}, then its Stokes flow for {args.stokes_time:g}",
           "machine": common.machine(), "configurations": {}}
    for name, env in CONFIGS.items():
        if args.allocator and name not in args.allocator:
            continue
        done = subprocess.run([sys.executable, __file__, "--worker", "--stokes-time", str(args.stokes_time)],
                              env=dict(os.environ, **env), capture_output=True, text=True, check=True)
        result = json.loads(done.stdout.strip().splitlines()[-1])
        out["configurations"][name] = {"environment": env, **result}
        rss = result["samples"]
        print(f"{name:<18} flow phase {result['flow_cpu_seconds']:.1f} CPU s, peak {result['peak_mib']:.0f} MiB; "
              "resident MiB (cache budget used, "
              "MiB) at t = " + ", ".join(f"{t:g}: {m:.0f} ({c:.0f})" for t, m, c in rss[1::2]), flush=True)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / args.output).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
