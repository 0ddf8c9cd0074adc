"""``ralf-hil memory-slope``: does any service's memory grow over a run?

Starts the three services as ``ralf-hil up`` does (:func:`workbench.launcher.supervise`),
samples each one's resident set (``/proc/PID/statm``) every ``--every`` seconds
from ``--skip`` seconds after the controller's first tick to the end of the run,
and prints the least-squares slope per service in MB/min with the first and last
sample. The start-up (imports, compiled kernels, zenoh buffers) is left out by
``--skip``; what is left is what a long run would accumulate.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

import numpy as np

from workbench.launcher import RigObserver, RigPlan, Supervision, supervise

PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mb(pid: int) -> float | None:
    """Resident set of ``pid`` in MB (None once it is gone)."""
    try:
        with open(f"/proc/{pid}/statm") as fh:
            return int(fh.read().split()[1]) * PAGE / 1e6
    except (OSError, ValueError, IndexError):
        return None


def slope_mb_per_min(samples: list[tuple[float, float]]) -> float:
    """Least-squares slope of (seconds, MB) samples, in MB per minute."""
    if len(samples) < 2:
        return float("nan")
    t, m = np.array(samples).T
    return float(np.polyfit(t, m, 1)[0] * 60.0)


def measure(duration_s: float, every_s: float, skip_s: float, clock: str, log_dir: Path) -> dict[str, Any]:
    """One run of ``duration_s`` s of control; RSS samples per service."""
    plan = RigPlan.local(rig_id=f"mem-{uuid.uuid4().hex[:6]}", clock=clock)
    observer = RigObserver(plan)
    samples: dict[str, list[tuple[float, float]]] = {}
    next_at = [0.0]

    def on_poll(sup: Supervision, _status: object) -> None:
        if sup.ready_at is None:
            return
        since = time.monotonic() - sup.ready_at
        if since < skip_s or since < next_at[0]:
            return
        next_at[0] = (since // every_s + 1) * every_s
        for name, proc in sup.procs.items():
            mb = rss_mb(proc.popen.pid)
            if mb is not None:
                samples.setdefault(name, []).append((since, mb))

    try:
        sup = supervise(plan, log_dir, lambda: observer.status, run_for_s=duration_s, startup_timeout_s=120.0, on_poll=on_poll, poll_s=0.5)
    finally:
        observer.close()
    return {
        "duration_s": duration_s,
        "clock": clock,
        "failure": sup.failure,
        "services": {
            name: {
                "samples": len(s),
                "first_mb": round(s[0][1], 2),
                "last_mb": round(s[-1][1], 2),
                "slope_mb_per_min": round(slope_mb_per_min(s), 4),
            }
            for name, s in samples.items()
            if s
        },
    }


def cmd_memory_slope(args: argparse.Namespace) -> int:
    log_dir = Path(args.log_dir) if args.log_dir else Path(tempfile.mkdtemp(prefix="ralf-memory-"))
    result = measure(args.duration, args.every, args.skip, args.clock, log_dir)
    for name, row in result["services"].items():
        print(f"{name:<11} {row['samples']:>4} samples  {row['first_mb']:8.2f} -> {row['last_mb']:8.2f} MB  slope {row['slope_mb_per_min']:+.4f} MB/min")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    if result["failure"]:
        print(f"run failed: {result['failure']} (logs in {log_dir})")
        return 1
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "memory-slope",
        help="run the rig and print each service's resident-memory slope (MB/min)",
        description="Start the three services as `ralf-hil up` does, read each one's resident set every --every seconds "
        "from --skip seconds after the first control tick to the end, and print its least-squares slope in MB/min.",
    )
    p.add_argument("--duration", type=_positive, default=600.0, help="seconds of control (default 600)")
    p.add_argument("--every", type=_positive, default=10.0, help="seconds between samples (default 10)")
    p.add_argument("--skip", type=_non_negative, default=20.0, help="seconds after the first tick before the first sample (default 20)")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime")
    p.add_argument("--log-dir", default=None, help="where the services' logs go (default: a temporary directory)")
    p.add_argument("--json", default=None, help="also write the result as JSON to this file")
    p.set_defaults(func=cmd_memory_slope)


def _positive(text: str) -> float:
    value = _non_negative(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be above 0")
    return value


def _non_negative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 <= value <= 1e6:  # NaN fails too
        raise argparse.ArgumentTypeError(f"{text}: give seconds from 0 to 1e6")
    return value
