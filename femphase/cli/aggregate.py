"""``femphase aggregate DIR``: a sweep's runs as one dataset (sweep.nc) and a summary table
(summary.csv), :mod:`femphase.aggregate`."""

from __future__ import annotations

import argparse
from pathlib import Path

from femphase.errors import InputError

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """`femphase aggregate DIR`: write sweep.nc and summary.csv and say what they hold."""
    # the command's implementation loads when it runs: the parser and the other commands start without it
    from femphase.aggregate import STATUSES, read_summary, write_aggregate

    try:
        paths = write_aggregate(args.directory)
    except (ValueError, OSError) as exc:
        raise InputError(str(exc)) from None
    rows = read_summary(paths["summary"])
    counts = {status: sum(row["status"] == status for row in rows) for status in STATUSES}
    print(f"{len(rows)} runs ({', '.join(f'{n} {s}' for s, n in counts.items() if n)})")
    for path in paths.values():
        print(path)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `aggregate` subcommand to the femphase command line."""
    parser = subparsers.add_parser(
        "aggregate", help="collect a sweep's runs into sweep.nc (xarray/netCDF) and summary.csv",
        description="Write DIR/sweep.nc (every run's global.csv and particles.csv on the sweep's axes × time "
                    "× particle) and DIR/summary.csv (one row per run: Ψ6, Ψ2^L and elongation averaged over "
                    "the last fifth of the last phase, period, T1 rate). docs/aggregation.md.",
    )
    parser.add_argument("directory", type=Path, help="sweep directory written by `femphase sweep` (holds sweep.json)")
    parser.set_defaults(func=run)
