"""``femphase run SCENE.toml -o DIR``: run a scene into a run directory
(:func:`femphase.run.runner.run_scene`)."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

__all__ = ["register", "run"]


def run(args: argparse.Namespace) -> int:
    """`femphase run`: run a scene into a run directory."""
    # the command's implementation loads when it runs: the parser and the other commands start without it
    from femphase.run.runner import check_resumed_method, run_scene
    from femphase.run.simulation import METHODS
    from femphase.scene import read_scene_data, scene_from_dict

    data = read_scene_data(args.scene, args.set)
    numerics, forced = data.get("numerics"), METHODS.get(args.method)
    given = numerics.get("scheme") if isinstance(numerics, dict) else None
    if forced is not None and given not in (None, forced):  # the same scene, cross-checked by the method
        warnings.warn(f"numerics.scheme = {given!r} is not used: --method {args.method} runs the scheme "
                      f"{forced!r} (the run's scene.toml records it)", stacklevel=2)
    if args.resume and forced is not None:  # a changed method first: the scene's checks below are its scheme's
        check_resumed_method(args.output, args.method)
    scene = scene_from_dict(data, Path(args.scene).parent, forced)
    progress = False if args.quiet else None
    state = run_scene(scene, args.output, resume=args.resume, overwrite=args.overwrite, method=args.method,
                      progress=progress, argv=sys.argv[1:] if args.argv is None else args.argv, sets=args.set,
                      status_interval=args.status_interval)
    print(f"femphase: {scene.name}: reached t = {state.time:g} after {state.step} steps; output in {args.output}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `run` subcommand to the femphase command line."""
    parser = subparsers.add_parser("run", help="run a scene into a run directory")
    parser.add_argument("scene", help="scene file (TOML), e.g. examples/single.toml")
    parser.add_argument("-o", "--output", required=True, help="run directory to write")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override a scene value, e.g. --set model.mu=10 --set phases.1.flow.rate=0.3")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true",
                      help="continue DIR from its checkpoint (the scene may extend durations, change later "
                           "phases' dt or the output cadence)")
    mode.add_argument("--overwrite", action="store_true",
                      help="replace the run in DIR (deletes femphase's files there, and only those: the run's outputs, "
                           "and the figures and comparison that plot and compare wrote into figures/ and compare/)")
    parser.add_argument("--method", default="fem", choices=["fem", "fd"],
                        help="fem: the finite-element solver with the scene's numerics.scheme; fd: the paper's "
                             "finite-difference scheme (numerics.scheme = \"fd-heun\")")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress bar and no status lines on the console (run.log has them)")
    parser.add_argument("--status-interval", type=_seconds, default=30.0, metavar="SECONDS",
                        help="wall time between status lines in run.log (and on the console without a "
                             "terminal); 0: after every call of the stepper (a step, or the adaptive scheme's call of up to "
                             "numerics.merged_steps steps) (default: 30)")
    parser.set_defaults(func=run, argv=None)


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not value >= 0:  # also NaN
        raise argparse.ArgumentTypeError(f"a number of seconds >= 0, not {text!r}")
    return value
