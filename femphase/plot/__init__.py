"""Figures: of a run directory (:mod:`femphase.plot.run`) and of a sweep
(:mod:`femphase.plot.sweep`); ``femphase plot DIR`` draws whichever DIR is."""

from femphase.plot.run import plot_run
from femphase.plot.sweep import plot_sweep

__all__ = ["plot_run", "plot_sweep"]
