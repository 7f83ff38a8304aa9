"""femphase: finite-element multi-phase-field simulations of dense soft suspensions in flow.

The package reads as its architecture, bottom layer first (a module imports only its own
layer or lower ones; ``tests/test_layers.py`` holds the contract, docs/architecture.md the
map):

``errors``, ``config``, ``registry``, ``tomlio``   what every layer may use
``model``         the physics: parameters, the free energy, the minimal ODE model
``placement``     initial particle positions
``fem``           P1 operators, periodic dofs, linear solvers, mesh files
``flows``         imposed velocity fields by name
``domains``       where the fields live: the structured channel (``grid``) and meshes (``mesh``)
``state``         one field per particle on its window
``timestepping``  the stepper and the time schemes
``analysis``      shape, order, T1 events, periods; the frame observables
``scene``         what to simulate (TOML), validated
``io``            run directories written and read back, checkpoints, provenance
``run``           the simulation loop and its trackers; ``run_scene``
``sweep``, ``aggregate``, ``compare``, ``oscillations``, ``plot``   applications
``cli``           the ``femphase`` command
``testing``       harnesses for the tests and benchmarks
"""

import logging
import time

__all__ = ["IMPORT_TIME", "__version__"]

__version__ = "0.2.0"

#: When this process first imported femphase (seconds since the epoch): run.json records
#: the modules whose source changed after it (:mod:`femphase.io.provenance`), since
#: a long-lived process (a sweep worker) runs the code it imported, not the checkout's.
IMPORT_TIME = time.time()

# a library configures no logging: records go nowhere until the application (the femphase
# CLI, a script) adds handlers to the "femphase" logger or the root logger
logging.getLogger(__name__).addHandler(logging.NullHandler())
