"""The ``femphase`` command line.

    femphase run SCENE.toml -o DIR [--set key=value ...] [--resume] [--method fem|fd]

Errors in a scene or a run (bad keys or values, a blown-up run) print one message and exit
with status 2 (scene) or 3 (run failed); nothing already written is removed.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings

from . import __version__
from .errors import BlowUpError, FemphaseError


def _run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .scene import read_scene_data, scene_from_dict
    from .simulation import run_scene

    scene = scene_from_dict(read_scene_data(args.scene, args.set), Path(args.scene).parent)
    progress = False if args.quiet else None
    state = run_scene(scene, args.output, resume=args.resume, method=args.method, progress=progress)
    print(f"femphase: {scene.name}: reached t = {state.time:g} after {state.step} steps; output in {args.output}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="femphase", description=__doc__.split("\n\n")[0])
    parser.add_argument("--version", action="version", version=f"femphase {__version__}")
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="run a scene into a run directory")
    run.add_argument("scene", help="scene file (TOML), e.g. examples/single.toml")
    run.add_argument("-o", "--output", required=True, help="run directory to write")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                     help="override a scene value, e.g. --set model.mu=10 --set phases.1.flow.rate=0.3")
    run.add_argument("--resume", action="store_true", help="continue from DIR/checkpoint.h5")
    run.add_argument("--method", default="fem", choices=["fem", "fd"],
                     help="fem: the finite-element solver with the scene's numerics.scheme; fd: the paper's "
                          "finite-difference scheme (numerics.scheme = \"fd-heun\")")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    run.set_defaults(func=_run)
    from . import compare, ode, plot

    for module in (ode, compare, plot):
        module.register_cli(commands)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    print(f"femphase: warning: {message}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    # BLAS threads oversubscribe small machines for no gain on these sparse problems
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    warnings.showwarning = _show_warning
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BlowUpError as exc:
        print(f"femphase: error: {exc}. The last good checkpoint is kept.", file=sys.stderr)
        return 3
    except (FemphaseError, ValueError) as exc:
        print(f"femphase: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("femphase: interrupted; the last checkpoint is kept (continue with --resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
