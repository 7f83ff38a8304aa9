"""Errors that femphase reports to the user as one clear message, without a traceback."""

from __future__ import annotations


class FemphaseError(Exception):
    """Base class: the CLI prints the message alone and exits with status 2."""


class SceneError(FemphaseError, ValueError):
    """A scene key or value is invalid. The message names the key, the value and what is valid."""

    def __init__(self, key: str, value: object, valid: str) -> None:
        self.key, self.value, self.valid = key, value, valid
        super().__init__(f"scene key '{key}' = {value!r} is invalid: {valid}")


class BlowUpError(FemphaseError, RuntimeError):
    """The time stepping produced NaN or φ far outside [0, 1]."""

    def __init__(self, step: int, time: float, reason: str) -> None:
        self.step, self.time, self.reason = step, time, reason
        super().__init__(f"the run blew up at step {step} (t = {time:g}): {reason}")


class ResolutionWarning(UserWarning):
    """A scene runs, but at a resolution known to bias its results (the message says how)."""
