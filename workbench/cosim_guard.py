"""``ralf-hil up --clock cosim`` of an FMU plant, in a child process.

A co-simulation steps the FMU in the process that runs it; an FMU crashing
in its native code after the launcher's check (a segmentation fault in
``fmi2DoStep`` at step 5,000) would end ``ralf-hil`` itself. So ``up``
runs such a co-simulation as a child ``ralf-hil up`` of the same arguments,
its output passed through, whose faulthandler writes to a file of this
process's; a child killed by a signal is one line naming the signal, the
FMI call in progress and the FMU (:func:`service_kit.crash_report.death_line`)
and exit 1. Costs one more Python start-up per such run; a run of the
built-in plant is not guarded (no native code of a user's).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from service_kit.crash_report import death_line

__all__ = ["FAULT_FILE_VARIABLE", "guarded_child_faults", "run_guarded"]

FAULT_FILE_VARIABLE = "_RALF_HIL_COSIM_FAULT_FILE"
"""Set in the child: where its faulthandler writes (not a ``RALF_`` setting)."""


def guarded_child_faults() -> TextIO | None:
    """In the guarded child: the open file its faulthandler writes to (keep it open); None elsewhere."""
    path = os.environ.get(FAULT_FILE_VARIABLE)
    if not path:
        return None
    return open(path, "w", encoding="utf-8")  # noqa: SIM115 - held for the process's life


def run_guarded(argv: Sequence[str], fmu: str) -> int:
    """Run ``ralf-hil`` with ``argv`` in a child process; its exit code, or for a death by signal one line and 1."""
    beat = getattr(sys.stderr, "heartbeat", None)
    if beat is not None:  # the child's own progress lines speak for the run: this process keeps quiet
        beat.stop()
    with tempfile.TemporaryDirectory(prefix="ralf-cosim-") as tmp:
        faults = Path(tmp) / "faults.txt"
        child = subprocess.Popen([sys.executable, "-P", "-m", "workbench", *argv], env={**os.environ, FAULT_FILE_VARIABLE: str(faults)})

        def forward(signum: int, _frame: Any) -> None:
            if signum != signal.SIGINT:  # Ctrl-C reaches the child with this process's group; the rest is passed on
                child.send_signal(signum)

        previous = {sig: signal.signal(sig, forward) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
        try:
            code = child.wait()
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
        if code >= 0:
            return code
        text = faults.read_text(errors="replace") if faults.exists() else ""
    print(f"rig failed: {death_line('the co-simulation', code, text, fmu)}", file=sys.stderr)
    return 1
