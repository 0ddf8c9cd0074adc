"""The controller's one path for run-time parameter changes (docs/calibration.md).

Every change of a calibration parameter of the XCP table
(:data:`controller.xcp_table.XCP_TABLE`: the PI gains, the OATF's first
stage), wherever it comes from, takes this path:

* **checked** against the table before it is taken: the value's limits and
  finiteness by the XCP map's own check
  (:meth:`service_kit.xcp.memory.MemoryLayout.check_write`, the value
  converted to its raw bytes as a master would write them), then the OATF's
  guards (a run without an OATF refuses its parameters; a design the
  filter's guards refuse, coefficient sum, delay, Nyquist, is refused);
* **queued** (at most :data:`PENDING_CAPACITY` changes waiting);
* **applied at a tick boundary**, before the tick that first uses it
  (:meth:`ParamPath.before_tick`): the PI integrators keep their state, the
  OATF its delay line and its stages' delays;
* **recorded**: listed in the run's ``config_changes`` (kind ``xcp``,
  ``param`` or ``schedule``, who sent it, the simulated time of the first
  tick that uses it, the physical values), published as a
  :class:`~protocol.messages.ParamChanged` event (``controller/param_changes``,
  so a recording holds it) and counted.

Its sources: the XCP slave (:mod:`controller.xcp_link`, kind ``xcp``), a
``ralf-hil param set`` or the live view's parameter panel
(:mod:`controller.param_commands`, kind ``param``) and the run's
``param_schedule`` setting (kind ``schedule``: each step at the first tick
at or after its ``at_s``, in simulated time, so a lockstep or co-simulated
run with a schedule is reproducible tick for tick).

Parameters are named ``controller.<name>`` outside the controller; values
are physical, in the table's unit (the PI gains in mV/rad; the law holds
V/rad, the table's raw value).
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

from controller.dsp_side import ConfigChangeTaken
from controller.loop import ControlLaw
from controller.oatf import OatfDesignError
from controller.xcp_table import controller_layout
from protocol.errors import ConfigError
from protocol.messages import ParamAnswer, ParamChanged, ParamInfo
from protocol.param_schedule import ParamStep
from service_kit.xcp.memory import Variable, Write, WriteRefused
from service_kit.xcp.packets import Err

__all__ = ["BOARD", "PENDING_CAPACITY", "ParamPath", "ParamRefused", "Pending"]

log = logging.getLogger(__name__)

BOARD: Final = "controller"
"""The prefix of the controller's parameter names (``controller.kp1``)."""
PENDING_CAPACITY: Final = 64
"""Accepted changes waiting for the next tick."""
PI: Final[dict[str, tuple[Literal["kp", "ki"], int]]] = {"kp1": ("kp", 0), "kp2": ("kp", 1), "ki1": ("ki", 0), "ki2": ("ki", 1)}
Kind = Literal["xcp", "param", "schedule"]


class ParamRefused(WriteRefused):
    """A change the path does not take: the XCP error code and a one-line reason."""


@dataclass(frozen=True)
class Pending:
    """One change waiting for its tick: the parameters it sets, where it came from."""

    changes: tuple[Write, ...]
    kind: Kind
    who: str
    request_id: str | None = None


def first_tick(at_s: float, period_s: float) -> int:
    """The first tick ``k`` whose time ``k * period_s`` is at or after ``at_s``."""
    k = max(0, math.ceil(at_s / period_s))
    while k > 0 and (k - 1) * period_s >= at_s:
        k -= 1
    while k * period_s < at_s:
        k += 1
    return k


class ParamPath:
    """The check, queue, apply and record of parameter changes (module docstring)."""

    def __init__(
        self,
        law: ControlLaw,
        period_s: float,
        config_changes: list[ConfigChangeTaken],
        schedule: Sequence[ParamStep] = (),
        *,
        counted: bool = False,
        publish: Callable[[bytes], None] | None = None,
        answer: Callable[[ParamAnswer], None] | None = None,
    ) -> None:
        self.law = law
        self.period_s = period_s
        self.config_changes = config_changes
        self.layout = controller_layout()
        self.variables: dict[str, Variable] = {v.name: v for v in self.layout.calibrations}
        """The table's calibration parameters, by their name in the table."""
        self.pi_gains = {name: law.pi_gain(term, joint) for name, (term, joint) in PI.items()}
        """The PI gains in effect (V/rad, raw), as the law holds them."""
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
        """Changes refused by :meth:`submit` (not by the XCP slave's own map checks: those it counts itself)."""
        self._seq = 0
        self._steps: list[tuple[int, Pending]] = self._schedule(schedule)
        self._next_step = self._steps[0][0] if self._steps else -1

    # -- names and values -----------------------------------------------------------------
    def variable(self, name: str) -> Variable:
        """The table's parameter ``controller.NAME`` (or ``NAME``); :class:`ParamRefused` if there is none."""
        short = name.removeprefix(BOARD + ".")
        v = self.variables.get(short)
        if v is None:
            known = ", ".join(f"{BOARD}.{n}" for n in self.variables)
            raise ParamRefused(Err.ERR_ACCESS_DENIED, f"no parameter {name!r} (known: {known})")
        return v

    def writes(self, name: str, physical: float) -> list[Write]:
        """``name`` set to ``physical`` as the XCP map takes a write of its raw value: the limits and
        finiteness checked by the map's own check; :class:`ParamRefused` naming the limit otherwise."""
        v = self.variable(name)
        raw = (float(physical) - v.offset) / v.factor
        try:
            return self.layout.check_write(v.address, struct.pack("<" + v.code, raw))
        except WriteRefused as exc:
            raise ParamRefused(
                exc.code, f"{BOARD}.{v.name} = {physical:g} {v.unit} refused: outside its limits {v.lower:g} .. {v.upper:g} {v.unit}".replace("  ", " ")
            ) from None

    def value(self, v: Variable) -> float:
        """The physical value in effect (NaN: an OATF parameter in a run without an OATF)."""
        law = self.law
        if v.name in PI:
            raw = self.pi_gains[v.name]
        elif law.oatf is None or not law.oatf.stages:
            return math.nan
        else:
            stage = law.oatf.stages[0]
            raw = stage.frequency_hz if v.name == "oatf_frequency_hz" else stage.zeta
        return v.to_physical(raw)

    def table(self) -> tuple[ParamInfo, ...]:
        """Every parameter with its unit, limits and value in effect (``ralf-hil param list``)."""
        out = []
        for v in self.layout.calibrations:
            value = self.value(v)
            out.append(
                ParamInfo(
                    name=f"{BOARD}.{v.name}",
                    unit=v.unit,
                    lower=v.lower,
                    upper=v.upper,
                    value=value if math.isfinite(value) else None,
                    description=v.description,
                )
            )
        return tuple(out)

    # -- the guards -----------------------------------------------------------------------
    def guard(self, changes: Sequence[Write]) -> None:
        """The OATF's guards on a change (the limits are the map's): :class:`ParamRefused` if refused."""
        oatf = {w.variable.name: float(w.raw) for w in changes if w.variable.name.startswith("oatf_")}
        if not oatf:
            return
        if self.law.oatf is None:
            raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no OATF (oatf_mode off)")
        try:
            self.law.oatf.design(*self._oatf_design(oatf))
        except (OatfDesignError, ValueError) as exc:
            raise ParamRefused(Err.ERR_OUT_OF_RANGE, f"OATF design refused: {exc}") from exc

    def _oatf_design(self, change: dict[str, float]) -> tuple[list[float], list[float]]:
        """The stages' frequencies and damping ratios with the first stage changed."""
        oatf = self.law.oatf
        assert oatf is not None
        stages = oatf.stages
        freqs = [s.frequency_hz for s in stages] or [self.law.config.oatf_frequency_hz]
        zetas = [s.zeta for s in stages] or [oatf.config.design_zeta]
        freqs[0] = change.get("oatf_frequency_hz", freqs[0])
        zetas[0] = change.get("oatf_zeta", zetas[0])
        return freqs, zetas

    # -- taking changes (any thread) ------------------------------------------------------
    def submit(self, changes: Sequence[Write], kind: Kind, who: str, request_id: str | None = None) -> None:
        """Queue a change the map took (limits checked) for the next tick, after the guards;
        :class:`ParamRefused` (counted) if refused."""
        try:
            self.guard(changes)
            with self._lock:
                if len(self._pending) >= PENDING_CAPACITY:
                    raise ParamRefused(Err.ERR_MEMORY_OVERFLOW, "too many changes waiting for the next tick")
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
        """The schedule as (first tick, change) in tick order, steps of one tick in one change;
        a step the table or the guards refuse is a one-line :class:`ConfigError`."""
        by_tick: dict[int, list[Write]] = {}
        for step in steps:
            try:
                (w,) = self.writes(step.name, step.value)
                if w.variable.name.startswith("oatf_") and self.law.oatf is None:
                    raise ParamRefused(Err.ERR_ACCESS_DENIED, "this run has no OATF (oatf_mode off)")
            except ParamRefused as exc:
                raise ConfigError(f"param_schedule: {step.name} at {step.at_s:g} s: {exc}") from None
            tick = first_tick(step.at_s, self.period_s)
            by_tick.setdefault(tick, [])
            by_tick[tick] = [x for x in by_tick[tick] if x.variable.name != w.variable.name] + [w]  # the later step of one tick wins
        return [(tick, Pending(tuple(ws), "schedule", "schedule")) for tick, ws in sorted(by_tick.items())]

    # -- the loop's side ------------------------------------------------------------------
    def due(self, tick: int) -> bool:
        """Anything to apply before ``tick`` (cheap: called before every tick)."""
        return bool(self._pending) or 0 <= self._next_step <= tick

    def before_tick(self, tick: int) -> None:
        """Apply the schedule's steps due at ``tick`` and the changes queued since the last tick,
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
        law = self.law
        oatf: dict[str, float] = {}
        for w in pending.changes:  # the raw values as written: the law holds raw values
            if w.variable.name not in PI:
                oatf[w.variable.name] = float(w.raw)
        if oatf and law.oatf is not None:
            try:
                law.oatf.update_modes(*self._oatf_design(oatf))
            except (OatfDesignError, ValueError) as exc:  # the design moved since the check (adaptive mode)
                self.failed[pending.kind] += 1
                log.warning("%s: OATF change %s not taken: %s", pending.kind, oatf, exc)
                self._answer(pending, tick, False, f"OATF design refused at tick {tick}: {exc}")
                return
        for w in pending.changes:
            if w.variable.name in PI:
                term, joint = PI[w.variable.name]
                law.set_pi_gain(term, joint, float(w.raw))
                self.pi_gains[w.variable.name] = law.pi_gain(term, joint)
        fields = {w.variable.name: w.physical for w in pending.changes}
        self.config_changes.append(ConfigChangeTaken(tick * self.period_s, pending.kind, fields, pending.who))
        self.applied[pending.kind] += 1
        log.info("parameters (%s, %s) from tick %d: %s", pending.kind, pending.who or "-", tick, fields)
        if self.publish is not None:
            event = ParamChanged(
                seq=self._seq,
                sim_time_s=tick * self.period_s,
                tick=tick,
                kind=pending.kind,
                who=pending.who,
                fields={f"{BOARD}.{k}": v for k, v in fields.items()},
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
                name=f"{BOARD}.{w.variable.name}",
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
