"""A generated text file (a table under docs/results/): written, checked against what it
should hold, or printed, with one line and an exit code for each way it can go."""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["emit"]


def emit(text: str, *, write: Path | None, check: Path | None, prog: str, regenerate: str) -> int:
    """Write ``text`` to ``write``, compare it with ``check`` (1 when the file differs, naming
    ``regenerate``, the command that rewrites it) or print it; 2 for a file that cannot be
    read or written, 0 otherwise."""
    if write is not None:
        try:
            write.write_text(text, encoding="utf-8")
        except OSError as exc:
            print(f"{prog}: cannot write {write}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        return 0
    if check is not None:
        try:
            current = check.read_text(encoding="utf-8")
        except OSError as exc:
            print(f"{prog}: cannot read {check}: {exc.strerror or exc}", file=sys.stderr)
            return 2
        if current != text:
            print(f"{prog}: {check} is out of date: {regenerate}", file=sys.stderr)
            return 1
        return 0
    sys.stdout.write(text)
    return 0
