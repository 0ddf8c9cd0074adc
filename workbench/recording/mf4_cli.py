"""``ralf-hil export --mf4 OUT.mf4 RUN.mcap`` and ``ralf-hil up --record run.mf4``:
a recording as an ASAM MDF 4.1 file (:mod:`workbench.recording.mf4`)."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

MF4_SUFFIX = ".mf4"


def is_mf4(path: str | None) -> bool:
    """``--record PATH`` writes MF4 when PATH ends in ``.mf4`` (any case), MCAP otherwise."""
    return bool(path) and Path(str(path)).suffix.lower() == MF4_SUFFIX


def output_problem(out: str) -> str | None:
    """Why ``out`` cannot be the MF4 file (one line), or None."""
    path = Path(out)
    if path.suffix.lower() != MF4_SUFFIX:
        return f"{out}: an MF4 file's name ends in {MF4_SUFFIX} (got {path.suffix or 'no suffix'!r})"
    if path.is_dir():
        return f"{out}: is a folder"
    folder = next(p for p in path.absolute().parents if p.exists())  # the folders below it are made
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        return f"{out}: {folder} is not a folder this user can write in"
    if path.exists() and not os.access(path, os.W_OK):
        return f"{out}: not writable"
    return None


def cmd_export(args: argparse.Namespace) -> int:
    problem = output_problem(args.mf4)
    if problem:
        print(f"ralf-hil export: {problem}", file=sys.stderr)
        return 2
    from workbench.recording.mf4 import export_file

    try:
        summary = export_file(args.path, args.mf4)
    except (OSError, ValueError) as exc:
        print(f"ralf-hil export: {args.path} -> {args.mf4}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 1
    print(summary.line())
    return 0


def record_mf4(run: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """``up --record run.mf4``: the run records MCAP into a temporary file as always, which
    is then exported to ``run.mf4`` and removed (kept beside ``run.mf4`` if the export fails).
    ``run`` starts the rig; ``up`` has checked its outputs (``run.mf4`` among them) before."""
    out = str(args.record)
    problem = output_problem(out)
    if problem:
        print(f"ralf-hil up: --record {problem}", file=sys.stderr)
        return 2
    folder = Path(tempfile.mkdtemp(prefix="ralf-mf4-"))
    mcap = folder / (Path(out).stem + ".mcap")
    args.record = str(mcap)
    try:
        code = run(args)
        if not mcap.exists():
            return code
        from workbench.recording.mf4 import export_file

        try:
            summary = export_file(mcap, out)
        except (OSError, ValueError) as exc:
            kept = Path(out).with_suffix(".mcap")
            shutil.move(str(mcap), kept)
            print(f"ralf-hil up: --record {out}: MF4 export failed ({' '.join(str(exc).split())}); the MCAP recording is kept in {kept}", file=sys.stderr)
            return code or 1
        print(f"exported to MF4: {summary.line()} (the run was recorded as MCAP into {mcap}, now removed)", file=sys.stderr)
        return code
    finally:
        args.record = out
        shutil.rmtree(folder, ignore_errors=True)


def register(subparsers: Any) -> None:
    """Add ``export`` to ``ralf-hil``."""
    p = subparsers.add_parser(
        "export",
        help="write a recording as an ASAM MDF 4.1 file (.mf4) for CANape, INCA, asammdf",
        description="Every numeric measurement of RUN.mcap as MDF channels with units, one channel group per topic, "
        "time = the rig's simulated time; the CAN frames as ASAM bus logging (CAN_DataFrame). docs/recording.md, MF4.",
    )
    p.add_argument("path", metavar="RUN.mcap")
    p.add_argument("--mf4", required=True, metavar="OUT.mf4", help="the MDF 4.1 file to write")
    p.set_defaults(func=cmd_export)
