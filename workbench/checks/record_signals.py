"""A run record's signals by name: the one place the checks read a
:class:`workbench.hil.RunRecord`.

Names (:func:`signal`):

``<column>``
    a controller column (``phi1``, ``defl1_in``, ``f_id_hz``, ...) over the
    column ``t_s``;
``truth.<field>[i]`` / ``truth.<field>``
    a field of the plant's ground truth (``truth.modal_frequencies_hz[0]``,
    ``truth.deflections_in[1]``, ``truth.payload_attached``) over its samples'
    ``sim_time_s``;
``events.<kind>``
    the plant's events of one kind (``events.payload``), value 1 at each
    event's ``sim_time_s`` (no event of a kind the plant sends: no sample);
``interrupts.<field>`` / ``interrupts.poles[i].<field>``
    a field of the DSP's interrupts (``interrupts.deadline_missed``,
    ``interrupts.poles[0].frequency_hz``: NaN where that pole is absent) over
    their ``sim_time_s``;
``counters.<name>``
    one of the controller's counters: one sample, at the run's end;
``health.<service>.<counter>``
    a counter of a service's last health message (``health.controller.deadline_miss_run_max``).

A name the record does not hold raises :class:`SignalNotInRecord`, one line
naming it and listing what the record holds, before any check computes.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Sequence
from typing import Any

import numpy as np

from workbench.checks.signal import Signal, SignalKind

PLANT_EVENT_KINDS = (
    "payload",
    "seed",
    "adc_bits",
    "sample_period",
    "hard_stop",
    "watchdog",
    "watchdog_cleared",
    "channel_fault",
    "channel_fault_cleared",
    "model_fault",
    "model_fault_cleared",
)
"""The kinds of event the plant sends (plant_emulator/service.py); an event kind also counts when the record holds one."""
MISS_COLUMNS = ("deadline_missed", "deadline_miss", "deadline_misses")
"""Names a per-tick deadline-miss column goes by, looked for first by :func:`deadline_misses`."""
_UNITS = (("_hz", "Hz"), ("_in", "in"), ("_v", "V"), ("_s", "s"), ("_rad", "rad"), ("_word", "count"))
_ANGLES = re.compile(r"^(phi|theta)(_ref|_shaped)?\d*$")
_TRUTH = re.compile(r"^truth\.(\w+)(?:\[(\d+)\])?$")
_POLE = re.compile(r"^interrupts\.poles\[(\d+)\]\.(\w+)$")
_POLE_FIELDS = ("frequency_hz", "damping_ratio", "magnitude", "confidence")
_SKIP = ("seq", "wall_time_s", "sim_time_s")


class SignalNotInRecord(LookupError):
    """A check asked for a signal the record does not hold (the message names it and what exists)."""

    def __str__(self) -> str:
        return str(self.args[0]) if self.args else ""


def unit_of(name: str) -> str:
    """A column's or field's unit from its name (``defl1_in`` -> in, ``phi1`` -> rad)."""
    base = re.sub(r"\[\d+\]$", "", name.rsplit(".", 1)[-1])
    if _ANGLES.match(base):
        return "rad"
    for suffix, unit in _UNITS:
        if base.endswith(suffix) or re.search(rf"{suffix}\d+$", base):
            return unit
    return ""


def _truth_fields(record: Any) -> dict[str, int | None]:
    """Truth field -> its width (None for a scalar field)."""
    if not record.truth:
        return {}
    first = record.truth[0]
    out: dict[str, int | None] = {}
    for name in type(first).model_fields:
        if name in _SKIP:
            continue
        value = getattr(first, name)
        out[name] = len(value) if isinstance(value, (tuple, list)) else None
    return out


def _interrupt_fields(record: Any) -> list[str]:
    if not record.interrupts:
        return []
    first = record.interrupts[0]
    return [n for n in type(first).model_fields if n not in _SKIP and n != "poles" and isinstance(getattr(first, n), (int, float, bool))]


def _max_poles(record: Any) -> int:
    return max((len(i.poles) for i in record.interrupts), default=0)


def _health_counters(record: Any) -> dict[str, list[str]]:
    return {svc: sorted(h.counters) for svc, h in (getattr(record, "health", None) or {}).items()}


def names(record: Any) -> list[str]:
    """Every signal name :func:`signal` takes for this record."""
    out = list(record.columns)
    for field, width in _truth_fields(record).items():
        out += [f"truth.{field}"] if width is None else [f"truth.{field}[{i}]" for i in range(width)]
    out += [f"events.{k}" for k in _event_kinds(record)]
    out += [f"interrupts.{f}" for f in _interrupt_fields(record)]
    out += [f"interrupts.poles[{i}].{f}" for i in range(_max_poles(record)) for f in _POLE_FIELDS]
    out += [f"counters.{c}" for c in record.counters]
    out += [f"health.{svc}.{c}" for svc, cs in _health_counters(record).items() for c in cs]
    return out


def _event_kinds(record: Any) -> list[str]:
    return list(dict.fromkeys([*PLANT_EVENT_KINDS, *(e.kind for e in record.events)]))


def _holdings(record: Any) -> str:
    """What the record holds, in one line."""
    parts = [f"columns {', '.join(record.columns) or '(none)'}"]
    truth = _truth_fields(record)
    if truth:
        parts.append("truth." + ", truth.".join(f if w is None else f"{f}[0..{w - 1}]" for f, w in truth.items()))
    else:
        parts.append("no truth samples")
    happened = sorted({e.kind for e in record.events})
    parts.append(f"events.<kind> ({', '.join(_event_kinds(record))}; in this run: {', '.join(happened) or 'none'})")
    fields = _interrupt_fields(record)
    if fields:
        pole = f", interrupts.poles[0..{_max_poles(record) - 1}].<{'|'.join(_POLE_FIELDS)}>" if _max_poles(record) else ""
        parts.append("interrupts." + ", interrupts.".join(fields) + pole)
    else:
        parts.append("no interrupts")
    parts.append(f"counters.<{'|'.join(record.counters) or 'none'}>")
    health = _health_counters(record)
    if health:
        services = ", ".join(f"{svc} ({len(cs)} counters)" for svc, cs in health.items())
        parts.append(f"health.<service>.<counter> of {services}; every name: workbench.checks.record_signals.names(record)")
    return "; ".join(parts)


def _missing(record: Any, name: str) -> SignalNotInRecord:
    close = difflib.get_close_matches(name, names(record), n=1, cutoff=0.75)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    return SignalNotInRecord(f"the record holds no signal {name!r}{hint}; it holds: {_holdings(record)}")


def _times(messages: Sequence[Any]) -> np.ndarray:
    return np.array([m.sim_time_s for m in messages], dtype=float)


def signal(record: Any, name: str) -> Signal:
    """The record's signal ``name`` (see the module's doc for the names); raises
    :class:`SignalNotInRecord` for one it does not hold."""
    __tracebackhide__ = True  # pytest: the test's line, then the one-line error
    if not isinstance(name, str) or not name:
        raise SignalNotInRecord(f"a signal name is a non-empty string, got {name!r}")
    columns = record.columns
    if name in columns and "." not in name:
        if "t_s" not in columns:
            raise SignalNotInRecord(f"the record's columns have no time column 't_s' for {name!r}")
        return Signal(np.asarray(columns["t_s"], float), np.asarray(columns[name], float), name, unit_of(name), "series", f"column {name}")
    if m := _TRUTH.match(name):
        field, index = m.group(1), m.group(2)
        width = _truth_fields(record).get(field, -1)
        if width == -1 or (width is None) != (index is None) or (index is not None and width is not None and int(index) >= width):
            raise _missing(record, name)
        values = [getattr(s, field) if index is None else getattr(s, field)[int(index)] for s in record.truth]
        return Signal(_times(record.truth), np.asarray(values, float), name, unit_of(field), "series", "plant ground truth")
    if name.startswith("events."):
        kind = name.removeprefix("events.")
        if kind not in _event_kinds(record):
            raise _missing(record, name)
        events = [e for e in record.events if e.kind == kind]
        return Signal(_times(events), np.ones(len(events)), name, "", "events", "plant events")
    if m := _POLE.match(name):
        index, field = int(m.group(1)), m.group(2)
        if field not in _POLE_FIELDS or index >= max(_max_poles(record), 1) or not record.interrupts:
            raise _missing(record, name)
        values = [_pole_value(i.poles, index, field) for i in record.interrupts]
        return Signal(_times(record.interrupts), np.asarray(values, float), name, unit_of(field), "series", "DSP interrupts")
    if name.startswith("interrupts."):
        field = name.removeprefix("interrupts.")
        if field not in _interrupt_fields(record):
            raise _missing(record, name)
        values = [float(getattr(i, field)) for i in record.interrupts]
        return Signal(_times(record.interrupts), np.asarray(values, float), name, unit_of(field), "series", "DSP interrupts")
    if name.startswith("counters."):
        counter = name.removeprefix("counters.")
        if counter not in record.counters:
            raise _missing(record, name)
        return Signal(np.array([record.sim_time_s]), np.array([record.counters[counter]], float), name, "", "count", "controller counters")
    if name.startswith("health."):
        svc, _, counter = name.removeprefix("health.").partition(".")
        held = _health_counters(record)
        if counter not in held.get(svc, []):
            raise _missing(record, name)
        run_kind: SignalKind = "run_max" if counter.endswith("_run_max") else "count"
        return Signal(np.array([record.sim_time_s]), np.array([record.health[svc].counters[counter]], float), name, "", run_kind, f"{svc} health")
    raise _missing(record, name)


def _pole_value(poles: Sequence[Any], index: int, field: str) -> float:
    if index >= len(poles):
        return math.nan
    value = getattr(poles[index], field)
    return math.nan if value is None else float(value)


def deadline_misses(record: Any) -> Signal:
    """The record's best account of missed deadlines for
    :func:`~workbench.checks.no_deadline_miss_streak`: a per-tick miss column when it
    has one (:data:`MISS_COLUMNS`), else the controller's longest run of misses
    (``health.controller.deadline_miss_run_max``), else its ``deadline_misses`` count."""
    for column in MISS_COLUMNS:
        if column in record.columns:
            return signal(record, column)
    if "deadline_miss_run_max" in _health_counters(record).get("controller", []):
        return signal(record, "health.controller.deadline_miss_run_max")
    return signal(record, "counters.deadline_misses")
