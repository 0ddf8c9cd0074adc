"""Properties of a run, built from the signal checks and the run's verdict.

A property is written ``NAME(ARG, ...)``; several may be given, and a run
violates the search's property when any one of them does not PASS (a check
that compared nothing, INVALID, is a violation too: the run did not show
what the property asks). Each is a check of :mod:`workbench.checks` or the
run's verdict (:mod:`workbench.verdict`):

``streak(N)``
    at most N deadline misses in a row (:func:`~workbench.checks.no_deadline_miss_streak`
    over :func:`~workbench.checks.deadline_misses`);
``within(SIGNAL, LOW, HIGH[, FROM_S])``
    every sample of SIGNAL from FROM_S on in ``[LOW, HIGH]``
    (:func:`~workbench.checks.stays_within`; ``within(counters.stale_episodes, 0, 0)``);
``mode(REL_TOL[, FROM_S])``
    the identified first mode ``f_id_hz`` within REL_TOL (a fraction) of the
    plant's true one (:func:`~workbench.checks.mode_frequency_within`);
``detected(CAUSE, DETECTION, WITHIN_S)``
    DETECTION's first sample within WITHIN_S of CAUSE's, when CAUSE came at all
    (:func:`~workbench.checks.detected_within`; a run without the cause holds it);
``valves_zero_within(CAUSE, N_MS)``
    both valve commands (``u1_v``, ``u2_v``) at 0 V within N_MS milliseconds of
    CAUSE and staying there (:func:`~workbench.checks.detected_within` over
    :func:`~workbench.search.valves.valves_at_zero`): CAUSE is a plant event
    (``events.channel_fault``: the first channel-fault insertion) or ``fault``
    (the earliest channel-fault start of the run's plant ``scenario`` setting);
    a run without the cause holds it;
``verdict(LEVEL)``
    the run's verdict at most LEVEL (PASS < DEGRADED < FAIL < INVALID);
``no_error()``
    the rig did not fail (no plant fault, no monitor stop).

A property naming no check, or a signal no record can hold, is refused in one
line before any run (:class:`PropertyError`).
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from controller.loop import ROW_NAMES, STIMULUS_NAMES
from protocol.messages import GroundTruth
from workbench.checks import deadline_misses, detected_within, mode_frequency_within, no_deadline_miss_streak, signal, stays_within
from workbench.checks.record_signals import PLANT_EVENT_KINDS
from workbench.checks.result import CheckResult, invalid, judged
from workbench.checks.signal import Signal
from workbench.search.valves import scenario_fault_start, valves_at_zero
from workbench.verdict import LEVELS

COLUMNS = frozenset(("t_s", *ROW_NAMES, *STIMULUS_NAMES, "oatf_hz", "irq_applied", "stale", "f_id_hz", "f_id2_hz", "zeta_id", "id_confidence", "tick"))
"""The controller record's columns a property may name."""
PREFIXES = ("truth.", "events.", "interrupts.", "counters.", "health.")
_CALL = re.compile(r"^\s*([a-z_]+)\s*\((.*)\)\s*$")
KNOWN = ("streak", "within", "mode", "detected", "valves_zero_within", "verdict", "no_error")


class PropertyError(ValueError):
    """A property that names no check, or a signal no record holds (one line)."""


def check_signal_name(name: str) -> None:
    """Refuse a signal name no record can hold (the column list, the truth's fields, the event kinds)."""
    if name in COLUMNS:
        return
    if name.startswith("truth."):
        field = re.sub(r"\[\d+\]$", "", name.removeprefix("truth."))
        if field in GroundTruth.model_fields:
            return
        known = [f"truth.{f}" for f in GroundTruth.model_fields]
    elif name.startswith("events."):
        if name.removeprefix("events.") in PLANT_EVENT_KINDS:
            return
        known = [f"events.{k}" for k in PLANT_EVENT_KINDS]
    elif name.startswith(PREFIXES):
        return  # interrupts, counters and health are judged against the first record (SignalNotInRecord)
    else:
        known = sorted(COLUMNS)
    close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise PropertyError(f"no run record holds a signal {name!r}{hint}")


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise PropertyError(f"{what} must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise PropertyError(f"{what} must be finite, got {text!r}")
    return value


@dataclass(frozen=True)
class Property:
    """One property: its text and the function that judges a run record."""

    text: str
    judge: Callable[[Any], CheckResult]


def _verdict(level: str) -> Callable[[Any], CheckResult]:
    limit = LEVELS.index(level)

    def judge(record: Any) -> CheckResult:
        name = f"verdict({level})"
        if record.verdict is None:
            return invalid(name, "the run was not judged", limit, "")
        got = LEVELS.index(record.verdict.level)
        return judged(name, got <= limit, got, limit, "", f"run verdict {record.verdict.line()} against at most {level}", None)

    return judge


def _no_error(record: Any) -> CheckResult:
    return judged("no_error()", record.error is None, 0 if record.error is None else 1, 0, "", f"rig failure: {record.error or 'none'}", None)


def _detected(cause: str, detection: str, within_s: float) -> Callable[[Any], CheckResult]:
    def judge(record: Any) -> CheckResult:
        c = signal(record, cause)
        if not (c.values != 0).any():
            return judged(f"detected({cause}, {detection})", True, 0, within_s, "s", f"{cause} never came: nothing to detect", None)
        return detected_within(c, signal(record, detection), within_s)

    return judge


FAULT_CAUSE = "fault"
"""``valves_zero_within``'s cause: the earliest channel-fault start of the run's plant scenario."""


def _valves_zero(cause: str, within_ms: float) -> Callable[[Any], CheckResult]:
    title = f"valves_zero_within({cause}, {within_ms:g} ms)"

    def judge(record: Any) -> CheckResult:
        if cause == FAULT_CAUSE:
            start = scenario_fault_start(record)
            when: Signal | float | None = start
        else:
            c = signal(record, cause)
            when = Signal.of(np.round(c.t, 9), c.values, c.name) if (c.values != 0).any() else None  # on the valves' 1 ns grid
        if when is None:
            return judged(title, True, 0, within_ms / 1e3, "s", f"{cause} never came: nothing to detect", None)
        result = detected_within(when, valves_at_zero(record), within_ms / 1e3, name=title)
        how = f"the controller stopped the run: {record.error}" if record.error else "no monitor stopped the run"
        return replace(result, sentence=f"{result.sentence}; {how}")

    return judge


def parse_property(text: str) -> Property:
    """A :class:`Property` from its text (:class:`PropertyError` on a bad one)."""
    m = _CALL.match(text)
    if not m:
        raise PropertyError(f"property {text!r} is not NAME(ARG, ...): streak(1), within(defl1_in, -0.3, 0.3), mode(0.1, 7), verdict(DEGRADED), no_error()")
    name, args = m.group(1), [a.strip() for a in m.group(2).split(",") if a.strip()]

    def arity(low: int, high: int) -> None:
        if not low <= len(args) <= high:
            want = str(low) if low == high else f"{low} to {high}"
            raise PropertyError(f"property {name}() takes {want} arguments, got {len(args)} in {text!r}")

    if name == "streak":
        arity(1, 1)
        n = _number(args[0], "streak's N")
        if n < 0 or n != int(n):
            raise PropertyError(f"streak's N is a count (0, 1, ...), got {args[0]!r}")
        return Property(text, lambda r: no_deadline_miss_streak(deadline_misses(r), int(n)))
    if name == "within":
        arity(3, 4)
        sig = args[0]
        check_signal_name(sig)
        low, high = _number(args[1], "within's LOW"), _number(args[2], "within's HIGH")
        if high < low:
            raise PropertyError(f"within({sig}, {args[1]}, {args[2]}): LOW is above HIGH")
        from_s = _number(args[3], "within's FROM_S") if len(args) == 4 else None
        return Property(text, lambda r: stays_within(signal(r, sig), low, high, from_s=from_s))
    if name == "mode":
        arity(1, 2)
        tol = _number(args[0], "mode's REL_TOL")
        if tol <= 0:
            raise PropertyError(f"mode's REL_TOL must be positive, got {args[0]!r}")
        start = _number(args[1], "mode's FROM_S") if len(args) == 2 else None
        return Property(text, lambda r: mode_frequency_within(signal(r, "f_id_hz"), signal(r, "truth.modal_frequencies_hz[0]"), rel_tol=tol, from_s=start))
    if name == "detected":
        arity(3, 3)
        check_signal_name(args[0])
        check_signal_name(args[1])
        within = _number(args[2], "detected's WITHIN_S")
        if within < 0:
            raise PropertyError(f"detected's WITHIN_S must not be negative, got {args[2]!r}")
        return Property(text, _detected(args[0], args[1], within))
    if name == "valves_zero_within":
        arity(2, 2)
        cause = args[0]
        if cause != FAULT_CAUSE:
            if not cause.startswith("events."):
                raise PropertyError(
                    f"valves_zero_within's CAUSE is a plant event (events.channel_fault) or {FAULT_CAUSE} (the scenario's first channel fault), got {cause!r}"
                )
            check_signal_name(cause)
        within_ms = _number(args[1], "valves_zero_within's N_MS")
        if within_ms < 0:
            raise PropertyError(f"valves_zero_within's N_MS must not be negative, got {args[1]!r}")
        return Property(text, _valves_zero(cause, within_ms))
    if name == "verdict":
        arity(1, 1)
        level = args[0].upper()
        if level not in LEVELS:
            raise PropertyError(f"verdict's LEVEL is one of {', '.join(LEVELS)}, got {args[0]!r}")
        return Property(text, _verdict(level))
    if name == "no_error":
        arity(0, 0)
        return Property(text, _no_error)
    close = difflib.get_close_matches(name, list(KNOWN), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise PropertyError(f"no property named {name!r}{hint}; known: {', '.join(KNOWN)}")


@dataclass(frozen=True)
class Properties:
    """Several properties; a run violates them when any one does not PASS."""

    items: tuple[Property, ...]

    @classmethod
    def parse(cls, texts: Sequence[str]) -> Properties:
        if not texts:
            raise PropertyError("no property given: a search needs at least one (--property streak(1))")
        return cls(tuple(parse_property(t) for t in texts))

    @property
    def text(self) -> str:
        return " and ".join(p.text for p in self.items)

    def judge(self, record: Any) -> list[CheckResult]:
        """Every property's result on ``record`` (SignalNotInRecord propagates: a bad name)."""
        return [p.judge(record) for p in self.items]
