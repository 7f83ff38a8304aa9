"""``femphase sweep SWEEP.toml -o DIR``: many runs of one scene on Dask, resumable
(:mod:`femphase.sweep`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from femphase.cli.interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED, sigterm_as_interrupt

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """`femphase sweep`: run (or continue) a sweep; exit 4 when some runs are not done."""
    # the command's implementation loads when it runs: the parser and the other commands start without it
    from femphase.sweep import EXIT_INCOMPLETE, run_sweep

    try:
        with sigterm_as_interrupt() as terminated:
            index = run_sweep(args.sweep, args.output, assignments=args.set, scheduler=args.scheduler,
                              workers=args.workers, log=lambda line: print(line, flush=True))
    except KeyboardInterrupt:
        print(f"femphase sweep: interrupted; rerun the same command to continue (sweep.json in {args.output} "
              "says where each run stands)", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    counts = {s: sum(r["status"] == s for r in index["runs"]) for s in ("done", "failed", "interrupted", "pending")}
    print("femphase sweep: " + ", ".join(f"{n} {s}" for s, n in counts.items() if n) + f"; index in "
          f"{Path(args.output) / 'sweep.json'}")
    return 0 if counts["done"] == len(index["runs"]) else EXIT_INCOMPLETE


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `sweep` subcommand to the femphase command line."""
    parser = subparsers.add_parser("sweep", help="run a sweep file's runs on Dask (resumable)",
                                   description="Parameter sweeps: many runs of one scene, executed on Dask, resumable (docs/sweeps.md).")
    parser.add_argument("sweep", help="sweep file (TOML), e.g. verification/sweeps/fig1a.toml")
    parser.add_argument("-o", "--output", required=True, help="sweep directory (rerun the command to continue it)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene value in every run (after the sweep file's [set]), e.g. "
                             "--set phases.1.duration=100")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="worker processes of the local cluster "
                       "(default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS",
                       help="a running Dask scheduler, e.g. tcp://10.0.0.1:8786 (dask-jobqueue, docs/sweeps.md)")
    parser.set_defaults(func=run)
