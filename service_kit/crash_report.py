"""A process killed by a signal, told in one line.

A service (and the launcher's isolated FMU check) runs with Python's
:mod:`faulthandler` on: a crash inside native code (an FMU's ``doStep``
dereferencing NULL, an ``abort()``) writes the Python frames of every
thread to the service's stderr, its log, before the process dies. The
frames name the call in progress: the FMU plant makes each FMI call through
a function named after it (``fmi2DoStep``, ``fmi3GetFloat64``, …,
plant_emulator/fmu/instance.py). :func:`death_line` turns an exit code and
that text into one line: ``plant ended by SIGSEGV (Segmentation fault) in
fmi2DoStep``.
"""

from __future__ import annotations

import faulthandler
import re
import signal
import sys
from pathlib import Path
from typing import TextIO

__all__ = ["crash_frames", "death_line", "enable", "fmi_call", "signal_text"]

_FRAME = re.compile(r'^\s*File "(?P<file>[^"]*)", line \d+ in (?P<name>\S+)')
_FMI_CALL = re.compile(r"^fmi[23][A-Z]\w*$")


def enable(stream: TextIO | None = None) -> None:
    """Dump every thread's Python frames to ``stream`` (default: stderr) on SIGSEGV, SIGFPE, SIGABRT, SIGBUS and SIGILL.

    A stream without a file descriptor (stderr captured in memory, as by
    pytest) is replaced by the process's own stderr, ``sys.__stderr__``."""
    target = stream or sys.stderr
    try:
        target.fileno()
    except (OSError, ValueError, AttributeError):  # io.UnsupportedOperation is an OSError
        target = sys.__stderr__
    if target is not None:
        faulthandler.enable(file=target, all_threads=True)


def signal_text(code: int) -> str:
    """``SIGSEGV (Segmentation fault)`` for exit code -11 (a death by signal); '' for an exit."""
    if code >= 0:
        return ""
    try:
        sig = signal.Signals(-code)
    except ValueError:
        return f"signal {-code}"
    described = signal.strsignal(sig)
    return f"{sig.name} ({described})" if described else sig.name


def crash_frames(text: str) -> list[str]:
    """The function names of the crashing thread, innermost first, from the
    last faulthandler dump in ``text`` (empty when there is none)."""
    start = text.rfind("Fatal Python error:")
    if start < 0:
        return []
    frames: list[str] = []
    in_current = False
    for line in text[start:].splitlines():
        if line.startswith("Current thread"):
            in_current = True
            continue
        if in_current:
            match = _FRAME.match(line)
            if not match:
                break
            frames.append(match.group("name"))
    return frames


def fmi_call(text: str) -> str | None:
    """The FMI call the crashing thread was in (None when none was)."""
    return next((name for name in crash_frames(text) if _FMI_CALL.match(name)), None)


def _tail(path: Path, max_bytes: int = 256 * 1024) -> str:
    try:
        with open(path, "rb") as fh:
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - max_bytes))
            return fh.read().decode("utf-8", "replace")
    except OSError:
        return ""


def death_line(name: str, code: int, log: str | Path | None = None, fmu: str | None = None) -> str:
    """``<name> exited with <code>``, or for a death by signal ``<name> ended by
    SIGSEGV (Segmentation fault)`` and, where its log's faulthandler dump
    names one, ``in fmi2DoStep`` (``of FMU <fmu>`` when given)."""
    if code >= 0:
        return f"{name} exited with {code}"
    line = f"{name} ended by {signal_text(code)}"
    text = _tail(log) if isinstance(log, Path) else (log or "")
    call = fmi_call(text)
    if call:
        line += f" in {call}" + (f" of FMU {fmu}" if fmu else "")
    elif text and crash_frames(text):
        line += f" in {crash_frames(text)[0]}"
    return line
