"""``python -m rig.bench``: the same as ``ralf-hil bench``."""

from rig.bench import main

raise SystemExit(main())
