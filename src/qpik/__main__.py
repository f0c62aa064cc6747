"""``python -m qpik`` is the ``qpik`` command."""

import sys

from qpik.app.cli import main

sys.exit(main())
