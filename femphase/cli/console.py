"""The console of ``femphase run``: the femphase logger's records on stderr, as ``femphase: …`` lines."""

from __future__ import annotations

import logging
import sys

__all__ = ["console_handler"]


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
