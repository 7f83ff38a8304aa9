"""Time stepping: the stepper and the time schemes it runs.

A :class:`~femphase.timestepping.stepper.Stepper` advances a :class:`~femphase.state.State`
by steps of fixed dt under one flow; the time scheme it runs is a
:class:`~femphase.timestepping.base.TimeScheme` chosen by name from :data:`SCHEMES`
(``numerics.scheme``). Importing this package registers the built-in schemes:

============= ===================================================================================
``euler``     first order (:mod:`femphase.timestepping.euler`)
``sav2``      second order at fixed dt (:mod:`femphase.timestepping.sav2`)
``adaptive``  error-controlled sav2 substeps, the default (:mod:`femphase.timestepping.adaptive`)
``fd-heun``   the paper's finite-difference scheme, the independent reference
              (:mod:`femphase.timestepping.fd`)
============= ===================================================================================
"""

from femphase.timestepping import adaptive, euler, fd, sav2  # noqa: F401  (register the schemes)
from femphase.timestepping.base import SCHEMES, TimeScheme
from femphase.timestepping.stepper import Stepper

__all__ = ["SCHEMES", "Stepper", "TimeScheme"]
