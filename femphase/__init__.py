"""femphase: finite-element multi-phase-field simulations of dense soft suspensions in flow."""

import logging

__version__ = "0.1.0"

# a library configures no logging: records go nowhere until the application (the femphase
# CLI, a script) adds handlers to the "femphase" logger or the root logger
logging.getLogger(__name__).addHandler(logging.NullHandler())
