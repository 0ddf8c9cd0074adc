"""The valves at zero after a fault: the ``valves_zero_within`` property's signals.

A run record's valve commands (``u1_v``, ``u2_v``, the D/A's volts) are put on
the plant's clock: tick ``k`` (the record's ``t_s = k·Ts``) answers the sample
the plant took at ``(k + 1)·Ts`` and its D/A update acts from then on
(lockstep and co-simulation, docs/fault-insertion.md#detection-latency), so
each command is dated ``t_s + Ts``, the clock of the plant's events and of its
channel-fault schedule. A run the controller ended early (a monitor under
policy ``stop``, a plant fault: the record's ``error``) sends both valves to
zero on its way out instead of the next tick's command (its ``valves_zeroed``
counter); that zero is the record's last valve sample, one period after the
last recorded command. The record keeps no row of that tick, the zero is
the controller's own counted act.

The detection is the first sample from which both valves read exactly zero to
the record's end (the D/A's zero code is 0.0 V exactly): the valves at zero
*and staying there*, so a command that passes through zero and moves on is no
detection.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np

from protocol.scenario_setting import parse_channel_faults
from workbench.checks import signal
from workbench.checks.signal import Signal

VALVES = ("u1_v", "u2_v")
"""The controller record's valve commands after the D/A (V)."""


def sample_period_s(record: Any) -> float:
    """The controller's sample period: ``1 / sample_rate_hz`` of its settings, else its tick times' step."""
    rate = (getattr(record, "config", None) or {}).get("sample_rate_hz")
    if rate:
        return 1.0 / float(rate)
    t = np.asarray(record.columns["t_s"], dtype=float)
    if t.size < 2:
        raise ValueError("the record states no sample rate and holds fewer than two ticks")
    return float(t[1] - t[0])


def stopped_with_zero(record: Any) -> bool:
    """The controller ended the run early (monitor stop, plant fault) and zeroed the valves on its way out."""
    return record.error is not None and int(record.counters.get("valves_zeroed", 0)) > 0


def valves_at_zero(record: Any) -> Signal:
    """1 from the first sample (plant clock) at which both valves read 0 V and stay there to the
    record's end, else 0; with the controller's closing zero after an early end (module doc)."""
    u1, u2 = (signal(record, name) for name in VALVES)
    ts = sample_period_s(record)
    t = np.round(u1.t + ts, 9)  # the plant's clock is a grid of sample periods: k·Ts to 1 ns, as its events
    zero = (u1.values == 0.0) & (u2.values == 0.0)
    if stopped_with_zero(record):
        t = np.append(t, round((float(t[-1]) if t.size else 0.0) + ts, 9))
        zero = np.append(zero, True)
    for_good = np.logical_and.accumulate(zero[::-1])[::-1]
    return Signal.of(t, for_good.astype(float), "valves_at_zero(u1_v, u2_v)")


def scenario_fault_start(record: Any) -> float | None:
    """The earliest ``start_s`` of the channel faults in the run's plant ``scenario`` setting (None: none)."""
    scenario = ((getattr(record, "settings", None) or {}).get("plant") or {}).get("scenario")
    if not scenario:
        return None
    text = json.dumps(scenario) if isinstance(scenario, (Mapping, list)) else str(scenario)
    starts = [f.start_s for f in parse_channel_faults(text).faults]
    return min(starts) if starts else None
