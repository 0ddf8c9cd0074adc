"""The host a number was measured on: CPU model and governor, whether
SCHED_FIFO and memory locking are permitted, isolated CPUs, PREEMPT_RT,
load average. Read from /proc and /sys (Linux); what cannot be read is
``None``, never guessed."""

from __future__ import annotations

import os
import platform
import resource
from pathlib import Path
from typing import Any


def _read(path: str) -> str | None:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return None


def cpu_model() -> str | None:
    text = _read("/proc/cpuinfo") or ""
    for line in text.splitlines():
        if line.lower().startswith(("model name", "hardware", "processor\t: arm")):
            return line.split(":", 1)[1].strip()
    return platform.processor() or None


def governors() -> list[str]:
    found = set()
    for p in Path("/sys/devices/system/cpu").glob("cpu[0-9]*/cpufreq/scaling_governor"):
        value = _read(str(p))
        if value:
            found.add(value)
    return sorted(found)


def sched_fifo_permitted() -> bool:
    """True if this process may switch itself to SCHED_FIFO (tried at priority 1 and undone)."""
    if not hasattr(os, "sched_setscheduler"):
        return False
    try:
        before = os.sched_getscheduler(0)
        param = os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    except (OSError, PermissionError):
        return False
    os.sched_setscheduler(0, before, param)
    return True


def mlock_permitted() -> bool:
    """True if mlockall would be allowed: unlimited RLIMIT_MEMLOCK or root."""
    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    return soft == resource.RLIM_INFINITY or os.geteuid() == 0


def preempt_rt() -> bool:
    return _read("/sys/kernel/realtime") == "1" or "PREEMPT_RT" in platform.version() or "PREEMPT RT" in platform.version()


def load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def host_info() -> dict[str, Any]:
    """Everything above, JSON-ready."""
    return {
        "hostname": platform.node(),
        "kernel": platform.release(),
        "kernel_version": platform.version(),
        "cpu_model": cpu_model(),
        "cpus": os.cpu_count(),
        "governors": governors(),
        "sched_fifo_permitted": sched_fifo_permitted(),
        "mlock_permitted": mlock_permitted(),
        "isolated_cpus": _read("/sys/devices/system/cpu/isolated") or "",
        "preempt_rt": preempt_rt(),
        "load_average": load_average(),
    }


def host_line(info: dict[str, Any] | None = None) -> str:
    """One line for a summary."""
    h = info or host_info()
    return (
        f"host: {h['cpu_model']} x{h['cpus']}, governor {','.join(h['governors']) or '?'}, "
        f"SCHED_FIFO {'yes' if h['sched_fifo_permitted'] else 'no'}, mlock {'yes' if h['mlock_permitted'] else 'no'}, "
        f"isolated CPUs {h['isolated_cpus'] or 'none'}, PREEMPT_RT {'yes' if h['preempt_rt'] else 'no'}, load {h['load_average']}"
    )
