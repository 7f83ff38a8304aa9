"""``femphase compare DIR_A DIR_B [-o OUT] [--fields]``: compare two runs, or a run and
external grid data (:mod:`femphase.compare`)."""

from __future__ import annotations

import argparse

from femphase.errors import InputError
from femphase.io.files import output_directory, writable_directory

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """`femphase compare DIR_A DIR_B`: write and print the per-frame differences."""
    # the command's implementation loads when it runs: the parser and the other commands start without it
    from femphase.compare import compare_runs, default_output, format_table, write_comparison

    # checked before anything is compared; an empty -o is refused, not taken for the default
    out = output_directory(default_output(args.b) if args.output is None else args.output)
    created = not out.exists()
    writable_directory(out)  # a path through a file, or not writable: refused before the work
    try:
        result = compare_runs(args.a, args.b, fields=args.fields)
    except (ValueError, OSError) as exc:  # this module's input errors; the CLI prints them as such
        if created and not any(out.iterdir()):
            out.rmdir()
        raise InputError(str(exc)) from None
    out = write_comparison(result, out)
    print(format_table(result))
    print(f"\nper-frame differences in {out / 'compare.csv'}, {out / 'compare.json'}, plot {out / 'compare.png'}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `compare` subcommand to the femphase command line."""
    parser = subparsers.add_parser(
        "compare",
        help="compare two runs, or a run and external grid data",
        description="Per-frame differences of observables, energies and (with --fields) fields between "
        "two run directories, or a run directory and grid data (.npz/.h5 with time, x, y, "
        "phi[F, N, ny, nx]; see `python -c 'import femphase.compare; help(femphase.compare)'`).",
    )
    parser.add_argument("a", metavar="DIR_A", help="run directory or grid data file")
    parser.add_argument("b", metavar="DIR_B", help="run directory or grid data file")
    parser.add_argument("-o", "--output", default=None,
                        help="output directory (default: DIR_B/compare; for a grid data file B, its name with "
                             "the suffix _compare beside it)")
    parser.add_argument("--fields", action="store_true",
                        help="also compare the fields (L2 with the lumped mass, L∞), per frame")
    parser.set_defaults(func=run)
