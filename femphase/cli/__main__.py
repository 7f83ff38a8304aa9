"""``python -m femphase.cli``: the ``femphase`` command without its console script."""

import sys

from femphase.cli import main

sys.exit(main())
