"""``python -m workbench.experiments``: the same as ``ralf-hil experiment``."""

import sys

from workbench.experiments.cli import main

sys.exit(main())
