"""``python -m rig`` is ``ralf-hil``."""

from rig.cli import main

raise SystemExit(main())
