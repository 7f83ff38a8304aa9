"""Errors that femphase reports to the user as one clear message, without a traceback."""

from __future__ import annotations

__all__ = ["BlowUpError", "ExtensionError", "FemphaseError", "FlowError", "FlowWarning", "InputError", "Interrupted",
           "ModelWarning", "NoRoomError", "OutputWarning", "ResolutionWarning", "RunStopped", "SceneError",
           "StiffnessWarning"]


class FemphaseError(Exception):
    """Base class: the CLI prints the message alone and exits with status 2."""


class SceneError(FemphaseError, ValueError):
    """A scene key or value is invalid. The message names the key, the value and what is
    valid; a key that starts with "-" (``--rate``, ``-o``) is a command-line option and is
    named as one, and an upper-case key (``SCENE``, ``SWEEP``) a command's file argument."""

    def __init__(self, key: str, value: object, valid: str) -> None:
        self.key, self.value, self.valid = key, value, valid
        kind = "option" if key.startswith("-") else "argument" if key.isupper() else "scene key"
        super().__init__(f"{kind} '{key}' = {value!r} is invalid: {valid}")


class InputError(FemphaseError, ValueError):
    """Bad input that is not a scene key (a file given to ``femphase compare`` or ``plot``)."""


class RunStopped(FemphaseError, RuntimeError):
    """A run that had started stopped at a step, for a reason of its own (its fields blew up,
    or it left the accuracy envelope with ``numerics.strict``): ``femphase run`` exits 3 and
    says what it kept, where bad input, refused before anything runs, exits 2."""


class ExtensionError(RunStopped):
    """An entry of the user's own module (an observable or a time scheme registered outside
    femphase) failed during a run: it raised, or returned what femphase cannot use."""

    def __init__(self, what: str, step: int, time: float, reason: str) -> None:
        self.step, self.time = step, time
        super().__init__(f"{what} failed at step {step} (t = {time:g}): {reason}")


class NoRoomError(RunStopped):
    """The device holding a run directory has no room for the next frame or checkpoint: the
    run stops before writing it (HDF5 files that fail mid-write leave the library in a state
    that crashed the process at exit), and its last checkpoint is kept."""


class BlowUpError(RunStopped):
    """The time stepping produced NaN or φ far outside [0, 1]."""

    def __init__(self, step: int, time: float, reason: str) -> None:
        self.step, self.time, self.reason = step, time, reason
        super().__init__(f"the run blew up at step {step} (t = {time:g}): {reason}")


class UnstableStepError(BlowUpError):
    """A step would go unstable, so the run stopped before it (exit and checkpoint as for a
    blow-up, :class:`BlowUpError`)."""

    def __init__(self, step: int, time: float, reason: str) -> None:
        self.step, self.time, self.reason = step, time, reason
        RuntimeError.__init__(self, f"the run stopped before step {step} (t = {time:g}): {reason}")


class FlowError(FemphaseError, RuntimeError):
    """A user's flow function (``type = "python"``) failed during a run: it raised, or gave
    NaN or inf. ``step``: the last step the run completed, once the stepper knows it."""

    def __init__(self, function: str, time: float, reason: str, step: int | None = None) -> None:
        self.function, self.time, self.reason, self.step = function, time, reason, step
        where = f"t = {time:g}" + ("" if step is None else f", after step {step}")
        super().__init__(f"the flow function {function} failed at {where}: {reason}")


class Interrupted(FemphaseError, RuntimeError):
    """The run was stopped by a signal (SIGINT, SIGTERM) between two steps; a checkpoint of
    that step is kept. ``exit_code`` is the shell's convention, 128 + the signal number."""

    def __init__(self, signal_name: str, exit_code: int, step: int, time: float) -> None:
        self.signal_name, self.exit_code, self.step, self.time = signal_name, exit_code, step, time
        super().__init__(f"interrupted by {signal_name} after step {step} (t = {time:g})")


class StopRun(Exception):
    """Raised by a tracker (``after_step`` or ``frame``) to end a run early, as finished for
    its purpose (a steady state reached, enough cycles recorded): :meth:`Simulation.run`
    ends after the frames of that step and returns the state. A run directory keeps a
    checkpoint there and marks the run "interrupted" with the reason, so ``--resume``
    continues it to the scene's end."""


class ResolutionWarning(UserWarning):
    """A scene runs, but at a resolution known to bias its results (the message says how)."""


class ModelWarning(UserWarning):
    """A scene runs, but with particles the diffuse-interface model does not resolve as
    particles (the message says which and why)."""


class FlowWarning(UserWarning):
    """A scene runs, but its flow crosses the walls or jumps at the periodic seam (the message
    says where and by how much)."""


class StiffnessWarning(UserWarning):
    """A scene runs, but a stiff term holds its steps far below dt (the message says which
    term, how far, and what lifts it)."""


class LockWarning(UserWarning):
    """A directory's lock could not be taken because its filesystem has no locks (some
    network filesystems): the command goes on, and nothing keeps a second process out."""


class OutputWarning(UserWarning):
    """A file a run directory holds from earlier is missing or damaged: the run goes on
    without it (the message names it and what is left out)."""
