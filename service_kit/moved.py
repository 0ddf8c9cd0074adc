"""Stand-alone tools that became ``ralf-hil`` subcommands: run the old
way (``python -m MODULE``), they say in one line where they went and exit
with status 2 instead of running."""

from __future__ import annotations

import sys
from typing import NoReturn


def exit_moved(old: str, new: str) -> NoReturn:
    """Print ``OLD is now `NEW``` on stderr and exit 2."""
    print(f"{old} is now `{new}`", file=sys.stderr)
    raise SystemExit(2)
