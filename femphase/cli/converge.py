"""``femphase converge SCENE.toml --h 1,0.5,0.25 -o DIR``: a convergence study in one command
(:mod:`femphase.converge`)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from femphase.cli.interrupts import EXIT_INTERRUPTED, EXIT_TERMINATED, sigterm_as_interrupt

__all__ = ["register", "run"]

#: Refinement options: attribute of the parsed arguments → parameter name.
REFINED = {"h": "h", "mesh": "mesh", "tolerance_t": "tolerance_t", "dt": "dt"}


def _items(text: str) -> list[str]:
    """The entries of a comma-separated list; an empty one ("1,,0.5") is refused, not skipped."""
    items = [item.strip() for item in text.split(",")]
    if not any(items):
        raise argparse.ArgumentTypeError("give at least one value")
    if not all(items):
        raise argparse.ArgumentTypeError(f"{text!r} has an empty entry; separate the values by single commas")
    return items


def _numbers(text: str) -> list[float]:
    """Levels of --h, --dt or --tolerance-t: numbers > 0 (said here, where a single bad value
    would otherwise be refused only as a study of one level)."""
    items = _items(text)
    try:
        numbers = [float(item) for item in items]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated list of numbers, e.g. 1,0.5,0.25")
    if not all(math.isfinite(number) and number > 0 for number in numbers):
        raise argparse.ArgumentTypeError(f"{text!r}: every value must be a finite number > 0, e.g. 1,0.5,0.25")
    return numbers


def _limit(limit: float, error_bar: float) -> str:
    """The limit to the error bar's second significant digit (at least six significant digits)."""
    if not (math.isfinite(limit) and math.isfinite(error_bar) and error_bar > 0 and limit != 0):
        return f"{limit:.6g}"
    digits = math.floor(math.log10(abs(limit))) - math.floor(math.log10(error_bar)) + 2
    return f"{limit:.{max(6, digits)}g}"


def run(args: argparse.Namespace) -> int:
    """`femphase converge`: run (or continue) the study, then print its table."""
    from femphase.converge import PARAMETERS, ConvergenceError, StudyIncomplete, option_of, run_convergence
    from femphase.sweep import EXIT_INCOMPLETE

    given = {name: getattr(args, name) for name in REFINED if getattr(args, name) is not None}
    refined = [name for name, values in given.items() if len(values) > 1]
    if len(refined) != 1:
        def option(name: str) -> str:  # as given: "--h 1,0.5"
            values = ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in given[name])
            return f"--{name.replace('_', '-')} {values}"

        # the options that refine, or else those given (with one value each)
        value = " ".join(option(name) for name in refined or given) or "none given"
        raise ConvergenceError("--h/--mesh/--tolerance-t/--dt", value,
                               "exactly one option with two or more values (the refined parameter); the others "
                               "take one value, which every run uses")
    parameter = refined[0]
    fixed = []  # the options with one value: --set assignments of every run
    for name, values in given.items():
        if name == "dt" and name != parameter:
            from femphase.scene import load_scene

            fixed += [f"phases.{k}.dt={values[0]!r}" for k in range(len(load_scene(args.scene).phases))]
        elif name != parameter:
            value = f'"{Path(values[0]).resolve()}"' if name == "mesh" else repr(values[0])
            fixed.append(f"{PARAMETERS[name][0]}={value}")
    fixed_keys = {assignment.partition("=")[0]: assignment for assignment in fixed}
    for assignment in args.set:  # the later --set would win silently, as the refined key's is refused
        key = assignment.partition("=")[0].strip()
        if key in fixed_keys:
            raise ConvergenceError("--set", assignment, f"a key no option of the study sets: "
                                   f"{option_of(key)} sets {fixed_keys[key]}; give one or the other")
    observables = [name.strip() for name in args.observable.split(",") if name.strip()]
    try:
        with sigterm_as_interrupt() as terminated:
            result = run_convergence(args.scene, args.output, parameter, given[parameter], observables,
                                     [*fixed, *args.set], expected_order=args.order, workers=args.workers,
                                     scheduler=args.scheduler, log=_progress)
    except KeyboardInterrupt:
        print(f"femphase converge: interrupted; rerun the same command to continue ({args.output})", file=sys.stderr)
        return EXIT_TERMINATED if terminated else EXIT_INTERRUPTED
    except StudyIncomplete as exc:  # as femphase sweep: some runs not done
        print(f"femphase converge: {exc}", file=sys.stderr)
        return EXIT_INCOMPLETE
    spacing = "effective spacing" if parameter == "mesh" else parameter
    print(f"\n{'observable':<16} {'order':>7} {'limit':>14} {'± error bar':>12}   error of each run ({spacing} = "
          + ", ".join(f"{level['s']:.4g}" for level in result["levels"]) + ")")
    for name, estimate in result["estimates"].items():
        errors = ", ".join("nan" if math.isnan(e) else f"{e:.3g}" for e in estimate.errors)
        order = f"{estimate.order:.2f}" + ("" if estimate.order_observed else "*")
        limit = _limit(estimate.limit, estimate.error_bar)
        print(f"{name:<16} {order:>7} {limit:>14} {estimate.error_bar:>12.3g}   {errors}"
              + (f"  ({estimate.note})" if estimate.note else ""))
    counted = [level for level in result["levels"] if math.isfinite(level["substeps"])]
    if counted:  # the adaptive scheme: what its controller did in the phase the observables come from
        print("substeps in the last phase (mean size; capped by the area-mode ceiling): " + ", ".join(
            f"{level['s']:.4g}: {level['substeps']:g} ({level['mean_substep']:.3g}; {level['capped']:g})"
            for level in counted))
    assumed = any(not estimate.order_observed for estimate in result["estimates"].values())
    print(("(* assumed, not observed)  " if assumed else "") + f"tables: {Path(args.output) / 'convergence.csv'}, "
          "convergence.nc; figure: convergence.png")
    return 0


def _progress(line: str) -> None:
    """A line of the study's sweep, as this command's (the sweep's prefix is its own)."""
    print(line.replace("femphase sweep:", "femphase converge:", 1), flush=True)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `converge` subcommand to the femphase command line."""
    parser = subparsers.add_parser(
        "converge", help="a convergence study: runs at several h, dt or tolerances, order and extrapolated limit",
        description="Run a scene at several resolutions (on Dask, resumable), and report per observable the "
                    "values, the observed order, the Richardson-extrapolated limit with its error bar and each "
                    "run's error (convergence.csv, convergence.nc, convergence.png in the output directory).")
    parser.add_argument("scene", help="scene file (TOML)")
    parser.add_argument("-o", "--output", required=True, help="study directory (rerun the command to continue it)")
    parser.add_argument("--h", type=_numbers, default=None, metavar="H1,H2,...",
                        help="mesh spacings (domain.h, lattice units), e.g. 1,0.5,0.25")
    parser.add_argument("--mesh", type=_items, default=None, metavar="FILE1,FILE2,...",
                        help="mesh files of a meshed scene's domain, coarse to fine (domain.mesh)")
    parser.add_argument("--tolerance-t", dest="tolerance_t", type=_numbers, default=None, metavar="T1,T2,...",
                        help="the adaptive scheme's tolerances (numerics.tolerance_t), e.g. 0.1,0.01,0.001")
    parser.add_argument("--dt", type=_numbers, default=None, metavar="DT1,DT2,...",
                        help="every phase's time step (time units), e.g. 10,5,2.5")
    parser.add_argument("--observable", default="mean_elongation",
                        help="comma-separated: period, mean_elongation, area, separation (default mean_elongation)")
    parser.add_argument("--order", type=float, default=None,
                        help="the formal order: used with two levels and when the observed order exceeds it "
                             "(default 2 for --h and --mesh, the scheme's order for --dt (euler: 1), 1 for "
                             "--tolerance-t)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene value in every run, e.g. --set phases.1.duration=2000")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="worker processes (default: one per core)")
    where.add_argument("--scheduler", default=None, metavar="ADDRESS", help="a running Dask scheduler")
    parser.set_defaults(func=run)
