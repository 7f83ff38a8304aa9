"""The console: the femphase logger's records on stderr, as ``femphase: …`` lines, for the
command line and for the sweeps' workers (light: logging and sys only, so that the command
line starts without the package's numerics)."""

from __future__ import annotations

import logging
import sys

__all__ = ["console_handler", "log_warning"]


class _ConsoleFormatter(logging.Formatter):
    """``femphase: message``, with ``warning:`` or ``error:`` after it at those levels (the
    form of the CLI's other messages)."""

    def format(self, record: logging.LogRecord) -> str:
        level = "" if record.levelno < logging.WARNING else f"{record.levelname.lower()}: "
        return f"femphase: {level}{record.getMessage()}"


def console_handler(level: int) -> logging.Handler:
    """A handler that writes the femphase logger's records of ``level`` and above to
    stderr (what ``femphase run`` attaches: INFO without a progress bar, WARNING with one
    or with ``-q``)."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setLevel(level)
    handler.setFormatter(_ConsoleFormatter())
    return handler


def log_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A ``warnings.showwarning`` that logs the message alone through the femphase logger:
    the console shows it as femphase's other warnings, and a running run's run.log keeps it
    (Python's own form adds the file, the line and the source of ``warnings.warn``)."""
    logging.getLogger("femphase").warning("%s", message)
