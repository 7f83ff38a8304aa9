"""``femphase plot DIR``: the figures of a run directory (:mod:`femphase.plot.run`), or of a
sweep directory (:mod:`femphase.plot.sweep`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from femphase.errors import InputError
from femphase.io.files import output_directory
from femphase.model.minimal import K_PAPER, ParameterError

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """`femphase plot DIR`: write the four figures and list them (a sweep's figures when DIR
    holds sweep.json, :mod:`femphase.aggregate`)."""
    # the command's implementation loads when it runs: the parser and the other commands start without it
    from femphase.aggregate import SWEEP_INDEX
    from femphase.plot.run import plot_run

    if args.output is not None:
        args.output = output_directory(args.output)  # checked before any figure is drawn
    if (args.directory / SWEEP_INDEX).is_file():
        return _plot_sweep(args)
    try:
        paths = plot_run(args.directory, args.output, ode_rate=args.ode_rate, ode_k=args.ode_k, fmt=args.format)
    except ParameterError as exc:  # ode_rate, ode_k: the options --ode-rate, --ode-k
        raise exc.as_option() from None
    except (ValueError, OSError) as exc:  # this module's input errors; the CLI prints them as such
        raise InputError(str(exc)) from None
    for path in paths.values():
        print(path)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `plot` subcommand to the femphase command line."""
    parser = subparsers.add_parser(
        "plot", help="figures of a run directory (snapshot, r(t) vs the ODE, limit cycle, order)",
        description="Figures of a run directory: the last frame, r(t) against the minimal model, the (r, 2θ) limit cycle, the order parameters.",
    )
    parser.add_argument("directory", type=Path, help="run directory written by `femphase run`, or a sweep "
                        "directory (sweep.json; its figures are described in docs/aggregation.md)")
    parser.add_argument("-o", "--output", default=None, help="output directory (default DIR/figures)")
    parser.add_argument("--ode-rate", type=float, default=None,
                        help="shear rate γ̇ of the ODE model (default: the run's, where its flow is a linear shear: "
                             "u = γ̇ y/Ly)")
    parser.add_argument("--ode-k", type=float, default=K_PAPER, help=f"ω = kγ̇ of the ODE (default {K_PAPER}, the paper's)")
    parser.add_argument("--format", default="png", choices=["png", "pdf", "svg"], help="image format (default png)")
    parser.set_defaults(func=run)


def _plot_sweep(args: argparse.Namespace) -> int:
    """`femphase plot DIR` on a sweep directory."""
    for option, value, default in (("--ode-rate", args.ode_rate, None), ("--ode-k", args.ode_k, K_PAPER)):
        if value != default:  # ignored without a word, an invalid value too
            raise InputError(f"{option} = {value!r} applies to a run directory, not to the sweep "
                             f"{str(args.directory)!r}; plot one of its runs/<id> for the ODE comparison")
    from femphase.plot.sweep import FIGURE_PANELS, plot_sweep

    try:
        paths = plot_sweep(args.directory, args.output, fmt=args.format)
    except (ValueError, OSError) as exc:  # this module's input errors; the CLI prints them as such
        raise InputError(str(exc)) from None
    for path in paths.values():
        print(path)
    for figure, panels in FIGURE_PANELS.items():  # a figure without a finite value is not drawn: say which
        if figure not in paths:
            measured = ", ".join(name for _, entries in panels for _, name in entries)
            print(f"femphase: no {figure} figure: no run that is done has a finite {measured}", file=sys.stderr)
    return 0
