"""Summaries of measured samples, ratios to floors, and the machine a run
was measured on. Every figure the bench reports is computed here from
samples taken in the same run; nothing is compared with stored numbers."""

from __future__ import annotations

import datetime as _dt
import math
import os
import platform
import sys
from collections.abc import Iterable, Mapping
from importlib import metadata
from typing import Any

import numpy as np

from workbench.hostinfo import host_info

PACKAGES = ("eclipse-zenoh", "python-can", "msgpack", "numpy", "scipy", "pydantic", "pydantic-settings", "rich", "canopen")


def summarize(samples_s: Iterable[float]) -> dict[str, float | int]:
    """Percentiles of round trips (or any latency) given in seconds, reported in µs."""
    data = np.asarray(list(samples_s), dtype=np.float64)
    if data.size == 0:
        raise ValueError("no samples to summarize")
    if not np.all(np.isfinite(data)) or np.any(data < 0):
        raise ValueError("latency samples must be finite and non-negative")
    p50, p99, p999 = np.percentile(data, [50.0, 99.0, 99.9])
    return {
        "n": int(data.size),
        "min_us": float(data.min() * 1e6),
        "mean_us": float(data.mean() * 1e6),
        "p50_us": float(p50 * 1e6),
        "p99_us": float(p99 * 1e6),
        "p999_us": float(p999 * 1e6),
        "max_us": float(data.max() * 1e6),
    }


def from_latency_stats(stats: Mapping[str, Any]) -> dict[str, float | int]:
    """A service's :class:`~protocol.messages.LatencyStats` (seconds) in the bench's units (µs)."""
    return {
        "n": int(stats["count"]),
        "p50_us": float(stats["p50"]) * 1e6,
        "p99_us": float(stats["p99"]) * 1e6,
        "p999_us": float(stats["p999"]) * 1e6,
        "max_us": float(stats["max"]) * 1e6,
    }


def ratio(measured: float | None, floor: float | None) -> float | None:
    """measured / floor, or None when either is missing or the floor is not positive."""
    if measured is None or floor is None:
        return None
    if not (math.isfinite(measured) and math.isfinite(floor)) or floor <= 0:
        return None
    return float(measured) / float(floor)


def ratios(measured: Mapping[str, Any], floor: Mapping[str, Any]) -> dict[str, float | None]:
    """p50, p99, p99.9 and max ratios of two summaries."""
    return {f"{key[:-3]}": ratio(measured.get(key), floor.get(key)) for key in ("p50_us", "p99_us", "p999_us", "max_us")}


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def load_average() -> list[float] | None:
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except (OSError, AttributeError):
        return None


def machine_info() -> dict[str, Any]:
    versions: dict[str, str | None] = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    usable: int | None
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count()
    return {
        "date": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": usable,
        "python": sys.version.split()[0],
        "python_implementation": platform.python_implementation(),
        "packages": versions,
        "load_average_at_start": load_average(),
        "host": host_info(),  # governor, SCHED_FIFO/mlock permitted, isolated CPUs, PREEMPT_RT (workbench/hostinfo.py)
    }
