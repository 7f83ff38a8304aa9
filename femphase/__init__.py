"""femphase: finite-element multi-phase-field simulations of dense soft suspensions in flow."""

import logging
import time

__version__ = "0.1.0"

#: When this process first imported femphase (seconds since the epoch): run.json records
#: the modules whose source changed after it (:mod:`femphase.io.provenance`), since
#: a long-lived process (a sweep worker) runs the code it imported, not the checkout's.
IMPORT_TIME = time.time()

# a library configures no logging: records go nowhere until the application (the femphase
# CLI, a script) adds handlers to the "femphase" logger or the root logger
logging.getLogger(__name__).addHandler(logging.NullHandler())
