"""Running scenes: a simulation is a state, a stepper per phase and trackers (py-pde style).

=============== =====================================================================
``simulation``  :class:`~femphase.run.simulation.Simulation`, the phase loop, and the
                :class:`~femphase.run.simulation.Tracker` interface with its
                :class:`~femphase.run.simulation.Frame`
``trackers``    progress bar, status log, frames kept in memory
``directory``   the tracker that writes a run directory
``guards``      the accuracy guard (warns, or stops with ``numerics.strict``)
``runner``      :func:`~femphase.run.runner.run_scene`: what ``femphase run`` does
=============== =====================================================================
"""

from femphase.errors import StopRun
from femphase.run.directory import RunDirectory
from femphase.run.guards import AccuracyGuard
from femphase.run.runner import run_scene
from femphase.run.simulation import Frame, Simulation, Tracker
from femphase.run.trackers import FrameRecorder, ProgressBar, StatusLog

__all__ = ["AccuracyGuard", "Frame", "FrameRecorder", "ProgressBar", "RunDirectory", "Simulation", "StatusLog",
           "StopRun", "Tracker", "run_scene"]
