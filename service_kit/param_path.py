"""The one path of a board's run-time parameter changes (docs/calibration.md),
shared by every board that serves parameters (the controller:
:mod:`controller.params`; the plant: :mod:`plant_emulator.params`).

A board's parameters are the calibration entries of its XCP map
(:class:`~service_kit.xcp.memory.MemoryLayout`). A change, from any source, is

* **checked** against the map: the value converted to its raw bytes as a
  master writes them and taken through the map's own check
  (:meth:`~service_kit.xcp.memory.MemoryLayout.check_write`: finite, inside
  the physical limits; a whole number for an integer parameter), then the
  board's guards (:meth:`ParamPath.guard`);
* **queued** (at most :data:`PENDING_CAPACITY` changes waiting);
* **applied at a step boundary** (:meth:`ParamPath.before_tick`: the
  controller's tick, the plant's SYNC), before the step that first uses it,
  by the board (:meth:`ParamPath.apply_changes`);
* **recorded**: handed to the board's list of changes taken (``record``:
  simulated time of its first step, kind, physical values, who), published as
  a :class:`~protocol.messages.ParamChanged` event on the board's
  ``param_changes`` key (its parameters by their full name, ``BOARD.NAME``)
  and counted.

Its sources: the board's XCP slave (kind ``xcp``), ``ralf-hil param set``
and the live view's panel (kind ``param``) and the board's ``param_schedule``
setting (kind ``schedule``: each step at the first step ``k`` with
``k * period_s >= at_s``, in simulated time, so a lockstep or co-simulated run
with a schedule is reproducible step for step).
"""

from __future__ import annotations

import logging
import math
import struct
import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Final, Literal

from protocol.errors import ConfigError
from protocol.messages import ParamAnswer, ParamChanged, ParamInfo
from protocol.param_schedule import ParamStep
from service_kit.xcp.memory import MemoryLayout, Variable, Write, WriteRefused
from service_kit.xcp.packets import Err

__all__ = ["PENDING_CAPACITY", "ApplyFailed", "Kind", "ParamPath", "ParamRefused", "Pending", "Recorder", "first_tick"]

log = logging.getLogger(__name__)

PENDING_CAPACITY: Final = 64
"""Accepted changes waiting for the next step."""
Kind = Literal["xcp", "param", "schedule"]
Recorder = Callable[[float, str, dict[str, float], str], None]
"""Takes a change applied: (simulated time of its first step, kind, physical values by short name, who)."""
_INTEGER_CODES: Final = frozenset("bBhHiIqQ")


class ParamRefused(WriteRefused):
    """A change the path does not take: the XCP error code and a one-line reason."""


class ApplyFailed(Exception):
    """A change the board could not apply at its step (its guards no longer held): the reason."""


@dataclass(frozen=True)
class Pending:
    """One change waiting for its step: the parameters it sets, where it came from."""

    changes: tuple[Write, ...]
    kind: Kind
    who: str
    request_id: str | None = None


def first_tick(at_s: float, period_s: float) -> int:
    """The first step ``k`` whose time ``k * period_s`` is at or after ``at_s``."""
    k = max(0, math.ceil(at_s / period_s))
    while k > 0 and (k - 1) * period_s >= at_s:
        k -= 1
    while k * period_s < at_s:
        k += 1
    return k


class ParamPath:
    """The check, queue, apply and record of one board's parameter changes (module docstring).

    A board overrides :meth:`value_raw` (the raw value in effect), :meth:`guard` (its own
    refusals of a change), :meth:`guard_step` (those of a scheduled step, checked at start)
    and :meth:`apply_changes` (the change made, at the step boundary)."""

    def __init__(
        self,
        board: str,
        layout: MemoryLayout,
        period_s: float,
        record: Recorder | None,
        schedule: Sequence[ParamStep] = (),
        *,
        counted: bool = False,
        publish: Callable[[bytes], None] | None = None,
        answer: Callable[[ParamAnswer], None] | None = None,
    ) -> None:
        self.board = board
        self.layout = layout
        self.period_s = period_s
        self.record = record
        self.variables: dict[str, Variable] = {v.name: v for v in layout.calibrations}
        """The map's calibration parameters, by their name in the table."""
        self.publish = publish
        """Sends a :class:`ParamChanged` (encoded) for each change taken; None: nobody listens."""
        self.answer = answer
        """Tells a command's sender that its change was taken (the refusals are answered at once, by the caller)."""
        self.counted = counted or bool(schedule)
        """Whether :meth:`counters` lists this path's counters (off by default: a run without the feature keeps its counters)."""
        self._pending: deque[Pending] = deque()
        self._lock = threading.Lock()
        self.applied: dict[str, int] = {"xcp": 0, "param": 0, "schedule": 0}
        self.failed: dict[str, int] = {"xcp": 0, "param": 0, "schedule": 0}
        self.refused = 0
        """Changes refused by :meth:`submit` (not by an XCP slave's own map checks: those it counts itself)."""
        self._seq = 0
        self._steps: list[tuple[int, Pending]] = self._schedule(schedule)
        self._next_step = self._steps[0][0] if self._steps else -1

    # -- the board's side (overridden) ------------------------------------------------------
    def value_raw(self, v: Variable) -> float:
        """The raw value of ``v`` in effect (NaN: not defined in this run)."""
        return math.nan

    def guard(self, changes: Sequence[Write]) -> None:
        """The board's own refusals of a change the map took: :class:`ParamRefused`."""

    def guard_step(self, w: Write) -> None:
        """The board's refusals of a scheduled step, when the run starts: :class:`ParamRefused`."""

    def apply_changes(self, pending: Pending, tick: int) -> None:
        """Make the change, in effect from ``tick``; :class:`ApplyFailed` if it no longer holds."""
        raise NotImplementedError

    # -- names and values -----------------------------------------------------------------
    def variable(self, name: str) -> Variable:
        """The table's parameter ``BOARD.NAME`` (or ``NAME``); :class:`ParamRefused` if there is none."""
        short = name.removeprefix(self.board + ".")
        v = self.variables.get(short)
        if v is None:
            known = ", ".join(f"{self.board}.{n}" for n in self.variables)
            raise ParamRefused(Err.ERR_ACCESS_DENIED, f"no parameter {name!r} (known: {known})")
        return v

    def writes(self, name: str, physical: float) -> list[Write]:
        """``name`` set to ``physical`` as the XCP map takes a write of its raw value: the limits and
        finiteness checked by the map's own check; :class:`ParamRefused` naming the limit otherwise."""
        v = self.variable(name)
        raw: float | int = (float(physical) - v.offset) / v.factor
        where = f"{self.board}.{v.name} = {physical:g} {v.unit}".replace("  ", " ").rstrip()
        if v.code in _INTEGER_CODES:
            if not (math.isfinite(raw) and raw == round(raw)):
                raise ParamRefused(Err.ERR_OUT_OF_RANGE, f"{where} refused: not one of its whole steps")
            raw = round(raw)
        try:
            return self.layout.check_write(v.address, struct.pack("<" + v.code, raw))
        except (WriteRefused, struct.error) as exc:
            code = exc.code if isinstance(exc, WriteRefused) else Err.ERR_OUT_OF_RANGE
            raise ParamRefused(code, f"{where} refused: outside its limits {v.lower:g} .. {v.upper:g} {v.unit}".rstrip()) from None

    def value(self, v: Variable) -> float:
        """The physical value in effect (NaN: not defined in this run)."""
        raw = self.value_raw(v)
        return v.to_physical(raw) if math.isfinite(raw) else math.nan

    def table(self) -> tuple[ParamInfo, ...]:
        """Every parameter with its unit, limits and value in effect (``ralf-hil param list``)."""
        out = []
        for v in self.layout.calibrations:
            value = self.value(v)
            out.append(
                ParamInfo(
                    name=f"{self.board}.{v.name}",
                    unit=v.unit,
                    lower=v.lower,
                    upper=v.upper,
                    value=value if math.isfinite(value) else None,
                    description=v.description,
                )
            )
        return tuple(out)

    # -- taking changes (any thread) ------------------------------------------------------
    def submit(self, changes: Sequence[Write], kind: Kind, who: str, request_id: str | None = None) -> None:
        """Queue a change the map took (limits checked) for the next step, after the guards;
        :class:`ParamRefused` (counted) if refused."""
        try:
            self.guard(changes)
            with self._lock:
                if len(self._pending) >= PENDING_CAPACITY:
                    raise ParamRefused(Err.ERR_MEMORY_OVERFLOW, "too many changes waiting for the next step")
                self._pending.append(Pending(tuple(changes), kind, who, request_id))
        except WriteRefused:
            if kind != "xcp":  # the XCP slave counts its own refusals (writes_refused)
                self.refused += 1
            raise

    def set(self, name: str, physical: float, kind: Kind, who: str, request_id: str | None = None) -> Write:
        """Check and queue ``name = physical`` (physical units); :class:`ParamRefused` (counted) if refused."""
        try:
            changes = self.writes(name, physical)
        except ParamRefused:
            self.refused += 1
            raise
        self.submit(changes, kind, who, request_id)
        return changes[0]

    def _schedule(self, steps: Sequence[ParamStep]) -> list[tuple[int, Pending]]:
        """The schedule as (first step, change) in step order, steps of one step in one change;
        a step the table or the guards refuse is a one-line :class:`ConfigError`."""
        by_tick: dict[int, list[Write]] = {}
        for step in steps:
            try:
                (w,) = self.writes(step.name, step.value)
                self.guard_step(w)
            except ParamRefused as exc:
                raise ConfigError(f"param_schedule: {step.name} at {step.at_s:g} s: {exc}") from None
            tick = first_tick(step.at_s, self.period_s)
            by_tick.setdefault(tick, [])
            by_tick[tick] = [x for x in by_tick[tick] if x.variable.name != w.variable.name] + [w]  # the later step of one tick wins
        return [(tick, Pending(tuple(ws), "schedule", "schedule")) for tick, ws in sorted(by_tick.items())]

    # -- the step's side ------------------------------------------------------------------
    def due(self, tick: int) -> bool:
        """Anything to apply before ``tick`` (cheap: called before every step)."""
        return bool(self._pending) or 0 <= self._next_step <= tick

    def before_tick(self, tick: int) -> None:
        """Apply the schedule's steps due at ``tick`` and the changes queued since the last step,
        in effect from ``tick`` on."""
        while self._steps and self._steps[0][0] <= tick:
            self._apply(self._steps.pop(0)[1], tick)
        self._next_step = self._steps[0][0] if self._steps else -1
        if self._pending:
            with self._lock:
                batches = list(self._pending)
                self._pending.clear()
            for pending in batches:
                self._apply(pending, tick)

    def _apply(self, pending: Pending, tick: int) -> None:
        try:
            self.apply_changes(pending, tick)
        except ApplyFailed as exc:
            self.failed[pending.kind] += 1
            log.warning("%s: %s change not taken at step %d: %s", pending.kind, self.board, tick, exc)
            self._answer(pending, tick, False, str(exc))
            return
        fields = {w.variable.name: w.physical for w in pending.changes}
        if self.record is not None:
            self.record(tick * self.period_s, pending.kind, fields, pending.who)
        self.applied[pending.kind] += 1
        log.info("%s parameters (%s, %s) from step %d: %s", self.board, pending.kind, pending.who or "-", tick, fields)
        if self.publish is not None:
            event = ParamChanged(
                seq=self._seq,
                sim_time_s=tick * self.period_s,
                tick=tick,
                kind=pending.kind,
                who=pending.who,
                fields={f"{self.board}.{k}": v for k, v in fields.items()},
            )
            self._seq += 1
            self.publish(event.__pydantic_serializer__.to_json(event))
        self._answer(pending, tick, True, "")

    def _answer(self, pending: Pending, tick: int, accepted: bool, reason: str) -> None:
        if self.answer is None or pending.request_id is None:
            return
        w = pending.changes[0]
        self.answer(
            ParamAnswer(
                seq=0,
                sim_time_s=tick * self.period_s,
                request_id=pending.request_id,
                name=f"{self.board}.{w.variable.name}",
                accepted=accepted,
                reason=reason,
                value=w.physical if accepted else None,
            )
        )

    def counters(self) -> dict[str, int]:
        """``param_*`` counters when the feature is in use (else none: the run's counters are unchanged)."""
        if not self.counted:
            return {}
        return {
            "param_changes_applied": self.applied["param"] + self.applied["schedule"],
            "param_changes_failed": self.failed["param"] + self.failed["schedule"],
            "param_sets_refused": self.refused,
        }
