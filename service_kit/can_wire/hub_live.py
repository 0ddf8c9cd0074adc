"""The wire arbiter's figures while it runs: one record per period.

:class:`PeriodFigures` turns the running :class:`~service_kit.can_wire.hub.HubStats`
of a :class:`~service_kit.can_wire.hub.Hub` into the figures of the period
since its previous call (wire time, the arbiter's clock): the mean and the
peak busy share of the load windows lying wholly in the period (the
co-simulation's definition; the period's own share when no window fits),
frames/s and bits/s of the period,
SYNC→TPDO1 (p50, max, smallest margin above the wire's physical floor) of
the pairs that ended in it, and the clients' counters (running totals:
deliveries filtered per client, outbox overruns). The record carries the
fields of the co-simulation's ``/can/bus_load`` (``bitrate``,
``busy_mean_pct``, ``busy_max_pct``, ``frames_per_s``, ``bits_per_s``) so
the same topic and schema hold it (docs/can-bus.md).

:func:`publish_periodically` (``python -m service_kit.can_wire.hub --live
FILE``) rewrites FILE atomically with the latest record every period; its
``seq`` counts the records, so a reader sees each new one once.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from service_kit.can_wire.bus_load import delay_stats
from service_kit.can_wire.timing import NS_PER_S


@dataclass
class _Mark:
    t_ns: int
    frames: int = 0
    bits: int = 0
    busy_ns: int = 0
    pairs: int = 0


class PeriodFigures:
    """The figures of each period of one hub (module docstring); ``now_ns``: the hub's wire clock at the call."""

    def __init__(self, hub: Any, start_ns: int) -> None:
        self.hub = hub
        self.seq = 0
        self._mark = _Mark(start_ns)

    def next(self, now_ns: int) -> dict[str, Any]:
        hub, st, m = self.hub, self.hub.stats, self._mark
        span_ns = max(0, now_ns - m.t_ns)
        frames, bits, busy_ns, pairs = st.frames, st.bits, st.busy_ns, st.sync_to_tpdo_total
        d_frames, d_bits, d_busy = frames - m.frames, bits - m.bits, busy_ns - m.busy_ns
        windows = _full_windows(st, m.t_ns, now_ns)
        if windows:  # as the co-simulation's: the mean and the peak of the load windows
            busy_pct, peak_pct = 100 * sum(windows) / (len(windows) * st.window_ns), 100 * max(windows) / st.window_ns
        else:  # a period shorter than a window, or before the first frame: the period's own share
            busy_pct = peak_pct = min(100.0, 100 * d_busy / span_ns) if span_ns > 0 else 0.0
        self.seq += 1
        out: dict[str, Any] = {
            "seq": self.seq,
            "source": "arbiter",
            "bitrate": st.bitrate,
            "span_s": span_ns / NS_PER_S,
            "frames": d_frames,
            "busy_mean_pct": busy_pct,
            "busy_max_pct": peak_pct,
            "frames_per_s": d_frames * NS_PER_S / span_ns if span_ns > 0 else 0.0,
            "bits_per_s": d_bits * NS_PER_S / span_ns if span_ns > 0 else 0.0,
            "window_ms": st.window_ns / 1e6,
        }
        n_new = min(pairs - m.pairs, len(st.sync_to_tpdo_ns))
        if n_new > 0:
            deltas = list(st.sync_to_tpdo_ns)[-n_new:]
            margins = list(st.sync_to_tpdo_margin_ns)[-n_new:]
            d = delay_stats({0: deltas})[0]
            out["sync_to_tpdo1_us"] = {"n": d.n, "p50": d.p50_ns / 1e3, "max": d.max_ns / 1e3}
            out["sync_to_tpdo1_floor_margin_min_us"] = min(margins) / 1e3
        c = hub.counters
        out["clients"] = {"connected": c.connected, "vanished": c.vanished, "overruns": c.overruns, "filtered": c.filtered, "refused_frames": c.refused_frames}
        out["filtered_per_client"] = dict(hub.filtered_per_client)
        self._mark = _Mark(now_ns, frames, bits, busy_ns, pairs)
        return out


def _full_windows(stats: Any, t0_ns: int, t1_ns: int) -> list[int]:
    """Busy ns of each load window lying wholly in [t0, t1) (windows without a frame: 0; none before the first frame)."""
    if stats.first_start_ns is None:
        return []
    origin, w = stats.first_start_ns, stats.window_ns
    first, end = -((origin - t0_ns) // w), (t1_ns - origin) // w  # ceil((t0 - origin) / w), floor((t1 - origin) / w)
    busy = dict(list(stats._windows.items()))
    return [busy.get(i, 0) for i in range(max(first, 0), end)]


def write_atomically(path: Path, record: Mapping[str, Any]) -> None:
    tmp = path.with_name(path.name + ".part")
    tmp.write_text(json.dumps(record))
    tmp.replace(path)


def publish_periodically(hub: Any, path: Path, period_s: float, stop: threading.Event) -> None:
    """Every ``period_s`` until ``stop``: the period's figures into ``path`` (a write that fails is skipped)."""
    clock = hub.wire.clock
    figures = PeriodFigures(hub, clock.now_ns())
    while not stop.wait(period_s):
        record = figures.next(clock.now_ns())
        try:
            write_atomically(path, record)
        except OSError:
            continue
