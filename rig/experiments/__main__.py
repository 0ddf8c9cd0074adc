"""``python -m rig.experiments``: the same as ``ralf-hil experiment``."""

import sys

from rig.experiments.cli import main

sys.exit(main())
