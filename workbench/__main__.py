"""``python -m workbench`` is ``ralf-hil``."""

from workbench.cli import main

raise SystemExit(main())
