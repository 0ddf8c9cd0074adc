"""``python -m workbench.bench``: the same as ``ralf-hil bench``."""

from workbench.bench import main

raise SystemExit(main())
