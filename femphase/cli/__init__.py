"""The ``femphase`` command line.

::

    femphase run SCENE.toml -o DIR [--set key=value ...] [--resume | --overwrite] [--method fem|fd]
                 [--status-interval SECONDS] [-q]
    femphase sweep SWEEP.toml -o DIR [--workers N | --scheduler ADDRESS]
    femphase aggregate DIR
    femphase plot DIR [-o OUT] [--ode-rate R] [--ode-k K]
    femphase compare DIR_A DIR_B [-o OUT] [--fields]
    femphase ode --rate R -o OUT
    femphase converge SCENE.toml -o DIR --h 1,0.5,0.25 | --tolerance-t … | --dt … [--observable …]
    femphase --import MODULE COMMAND …   (extensions: MODULE registers flows, observables, schemes)

One module per command (:mod:`femphase.cli.run`, ``sweep``, ``aggregate``, ``plot``,
``compare``, ``ode``, ``converge``), each with ``register(subparsers)`` and ``run(args)``; argparse lives
here only.

Exit codes: 0 done; 2 bad input (a scene key or value, a command-line value, a run directory
that cannot be used: one message naming the key, the value and what is valid); 3 the run
blew up (the last good checkpoint is kept); 130 interrupted by SIGINT (Ctrl-C), 143 by
SIGTERM (``timeout``, Slurm, ``docker stop``): the run stops after the current step, keeps a
checkpoint of it, marks run.json "interrupted" and can be continued with ``--resume``;
1 an internal error (a bug: rerun with ``--traceback`` and report it); 4 (``femphase sweep``)
some runs failed or were interrupted (sweep.json says which and why; rerun to continue).
Nothing already computed is removed by any error.

Console (stderr): on a terminal a progress bar; without one (a batch job) the status lines
of :class:`femphase.run.trackers.StatusLog` instead; with ``-q`` neither. Warnings and errors always.
The run directory's run.log has the status lines, warnings and errors in every case.
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import re
import sys
import traceback
import warnings

from femphase import __version__
from femphase.cli import aggregate, compare, converge, ode, plot, run, sweep
from femphase.errors import BlowUpError, FemphaseError, FlowError, Interrupted, RunStopped, SceneError
from femphase.io.console import console_handler, log_warning
from femphase.registry import EXTENSIONS_VARIABLE, import_extensions

__all__ = ["COMMANDS", "build_parser", "main"]

#: The logger every femphase module logs to; `femphase run` gives it a console handler.
LOGGER = logging.getLogger("femphase")

#: The subcommands, in the order ``femphase --help`` lists them.
COMMANDS = (run, ode, compare, plot, sweep, aggregate, converge)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="femphase", description=__doc__.split("\n\n")[0].replace("``", ""))
    parser.add_argument("--version", action="version", version=f"femphase {__version__}")
    parser.add_argument("--traceback", action="store_true", help="show the Python traceback of an error (for bug reports)")
    parser.add_argument("--import", dest="extensions", action="append", default=[], metavar="MODULE",
                        help="import MODULE first: a module that registers flows, observables, schemes (repeatable; "
                             "looked up on PYTHONPATH, then in the working directory; sweeps' workers import it too, "
                             f"through {EXTENSIONS_VARIABLE})")
    commands = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.register(commands)
    for subparser in commands.choices.values():  # after the command too, where its error message sends users
        subparser.add_argument("--traceback", action="store_true", default=argparse.SUPPRESS,
                               help="show the Python traceback of an error (for bug reports)")
    return parser


def main(argv: list[str] | None = None) -> int:
    # BLAS threads oversubscribe small machines for no gain on these sparse problems
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    warnings.showwarning = log_warning
    args = build_parser().parse_args(_attach_negative_values(sys.argv[1:] if argv is None else argv))
    if argv is not None:
        args.argv = list(argv)
    # status lines on the console only where no progress bar shows them (tqdm draws only on
    # a terminal), and not with -q
    status_lines = not getattr(args, "quiet", True) and not sys.stderr.isatty()
    console, level = console_handler(logging.INFO if status_lines else logging.WARNING), LOGGER.level
    LOGGER.addHandler(console)
    LOGGER.setLevel(logging.INFO)
    try:
        blank = [name for name in args.extensions if not name.strip()]
        if blank:
            raise SceneError("--import", blank[0], "the name of a module to import (it is empty)")
        if args.extensions:  # in the environment, so that sweeps' and studies' workers import them too
            os.environ[EXTENSIONS_VARIABLE] = ",".join(
                part for part in [os.environ.get(EXTENSIONS_VARIABLE, ""), *args.extensions] if part)
        import_extensions()
        return args.func(args)
    except BaseException as exc:  # every error ends in one message and a documented code
        if args.traceback:
            traceback.print_exc()
        code, message = _report(exc)
        if code is None:
            raise
        print(f"femphase: {message}", file=sys.stderr)
        return code
    finally:  # main may be called again in this process (tests): no second handler
        LOGGER.removeHandler(console)
        LOGGER.setLevel(level)


#: A value that starts like a negative number: "-1", "-0.5", "-1,0.5", "-1e-3".
_NEGATIVE_VALUE = re.compile(r"-\.?\d")


def _attach_negative_values(argv: list[str]) -> list[str]:
    """``--option -1,0.5`` as ``--option=-1,0.5``.

    argparse reads a token that starts with "-" as an option unless it is a plain negative
    number, so a list such as ``--h -1,0.5`` stopped with "expected one argument" instead of
    the option's own message naming the value and what is valid.
    """
    joined: list[str] = []
    for token in argv:
        previous = joined[-1] if joined else ""
        if _NEGATIVE_VALUE.match(token) and previous.startswith("--") and previous != "--" and "=" not in previous:
            joined[-1] = f"{previous}={token}"
        else:
            joined.append(token)
    return joined


def _report(exc: BaseException) -> tuple[int | None, str]:
    """(exit code, message) for an error; code None: let it propagate (SystemExit)."""
    if isinstance(exc, SystemExit):
        return None, ""
    # what a stopped run kept (femphase.run.runner.run_scene says; other commands keep nothing to continue)
    kept = getattr(exc, "kept", None)
    lost = {
        # a run stopped without checkpoints (output.checkpoint = false) kept its frames only
        "frames": "its frames so far are kept; it writes no checkpoint (output.checkpoint = false) and cannot be "
                  "continued",
        "nothing": "it stopped before its first checkpoint and cannot be continued: rerun it with --overwrite",
    }.get(kept)

    def said(checkpoint: str) -> str:
        return checkpoint if kept == "checkpoint" else lost or ""

    if isinstance(exc, (Interrupted, KeyboardInterrupt)):
        kept_now = said("the checkpoint of that step is kept (continue with --resume)" if isinstance(exc, Interrupted)
                        else "the last checkpoint is kept (continue with --resume)")
        return (exc.exit_code if isinstance(exc, Interrupted) else 130,
                (f"{exc}" if isinstance(exc, Interrupted) else "interrupted") + (f"; {kept_now}" if kept_now else ""))
    if isinstance(exc, (RunStopped, FlowError)):
        what = said("the last good checkpoint is kept" if isinstance(exc, (BlowUpError, FlowError)) else
                    "the last checkpoint is kept")
        return 3, f"error: {exc}." + (f" {what[0].upper()}{what[1:]}." if what else "")
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):  # a full disk is no bug
        what = said("the last checkpoint is kept (free space and continue with --resume)")
        return 3, (f"error: cannot write {exc.filename or 'an output'}: {exc.strerror}."
                   + (f" {what[0].upper()}{what[1:]}." if what else ""))
    if isinstance(exc, FemphaseError):
        return 2, f"error: {exc}"
    return 1, (f"internal error ({type(exc).__name__}: {exc}); this is a bug: rerun with --traceback and "
               "report the output")
