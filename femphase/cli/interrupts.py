"""SIGTERM handled as Ctrl-C by the commands that run many runs (``sweep``, ``converge``):
``timeout``, Slurm and ``docker stop`` send it, and the runs then stop as at Ctrl-C, with
their checkpoints, so that the same command continues them. SIGINT stops them too where the
process started with it ignored (a script's background job), as it stops ``femphase run``."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["EXIT_INTERRUPTED", "EXIT_TERMINATED", "sigterm_as_interrupt"]

#: Exit codes of an interrupted command: 128 + the signal's number, as a shell reports it.
EXIT_INTERRUPTED, EXIT_TERMINATED = 128 + signal.SIGINT, 128 + signal.SIGTERM


@contextmanager
def sigterm_as_interrupt() -> Iterator[list[int]]:
    """Within the block SIGTERM raises KeyboardInterrupt, and so does SIGINT where it was
    ignored (Python leaves an inherited SIG_IGN in place: a sweep started by a script in the
    background ran on through SIGINT); yields the list that records each SIGTERM received
    (empty after a Ctrl-C), to choose the exit code."""
    terminated: list[int] = []

    def terminate(number, frame):
        terminated.append(number)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, terminate)
    ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield terminated
    finally:
        signal.signal(signal.SIGTERM, previous)
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
