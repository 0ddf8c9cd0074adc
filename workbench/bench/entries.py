"""What every bench item shares: its context (:class:`BenchContext`), an
empty result, :class:`Skip` for a measurement that cannot run, and the
measurement entries (:func:`latency`, :func:`latency_vs_value`,
:func:`scalar`) with their ratios to a floor (see :mod:`workbench.bench.items`
for the result's layout)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workbench.bench.stats import ratio, ratios

__all__ = ["BenchContext", "Skip", "latency", "latency_vs_value", "new_result", "requires", "scalar"]


class Skip(Exception):
    """A measurement cannot run yet (a module it needs is missing)."""


@dataclass
class BenchContext:
    quick: bool = False
    duration_s: float = 10.0
    iterations: int = 2000
    warmup: int = 100
    log_dir: Path = field(default_factory=lambda: Path("/tmp"))
    floors_only: bool = False
    say: Callable[[str], None] = lambda text: None
    rates: tuple[tuple[float, float | None], ...] = ()
    """realtime: (rate Hz, seconds or None = ``duration_s``) per run (empty: 200 Hz and 1 kHz)."""
    batch_period_s: float = 0.2
    """realtime: batch size = this many seconds of samples (> the DSP's 100 ms emulated latency: slack for the deadline)."""
    floor_s: float = 5.0
    """realtime: seconds of the sleep-only loop per rate (at most the run's own)."""
    burners: int = 0
    """realtime: CPU-burning processes running during the floor and the rig (a loaded host)."""
    rt_priority: int = 0
    cpu_affinity: str = ""
    """realtime: RALF_RT_PRIORITY / RALF_CPU_AFFINITY for the controller and the plant (opt-in measures)."""
    rt_cpu_latency_us: int = -1
    """realtime: RALF_RT_CPU_LATENCY_US for the controller and the plant, and the sleep-only floor's (-1: off)."""


def new_result() -> dict[str, Any]:
    return {"status": "ok", "measurements": {}, "config": {}, "notes": [], "errors": [], "skipped": []}


def requires(*modules: str) -> None:
    """Raise :class:`Skip` naming the first module that does not import."""
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise Skip(f"{module} does not import yet ({type(exc).__name__}: {exc})") from None


def latency(summary: Mapping[str, Any], floor: str | None = None, floor_summary: Mapping[str, Any] | None = None, **extra: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"kind": "latency", **summary}
    if floor is not None:
        entry["floor"] = floor
        entry["ratio"] = ratios(summary, floor_summary) if floor_summary is not None else None
    entry.update(extra)
    return entry


def latency_vs_value(summary: Mapping[str, Any], floor: str, floor_value_us: float, **extra: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"kind": "latency", **summary, "floor": floor, "floor_value_us": floor_value_us}
    entry["ratio"] = {key[:-3]: ratio(summary.get(key), floor_value_us) for key in ("p50_us", "p99_us", "p999_us", "max_us")}
    entry.update(extra)
    return entry


def scalar(value: float | int | None, unit: str, floor: str | None = None, floor_value: float | None = None, **extra: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"kind": "scalar", "value": value, "unit": unit}
    if floor is not None:
        entry["floor"] = floor
        entry["floor_value"] = floor_value
        entry["ratio"] = ratio(value, floor_value) if value is not None else None
    entry.update(extra)
    return entry
