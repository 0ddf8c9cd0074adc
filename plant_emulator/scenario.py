"""Scenario inputs for the plant: timed, discontinuous changes.

The thesis's future work (§5.3) asks for discontinuous parameter changes
(picking up and releasing the payload) to measure the identifier's delay,
and for finer converters.  A :class:`Scenario` is a list of timed
:class:`ScenarioEvent` s; :meth:`Scenario.advance` integrates the arm and
applies each event at its time (to the plant's internal step), so an
offline experiment and the plant service (which receives the same three
kinds as ``protocol.messages.ScenarioCommand`` on its test port) do the
same thing.

Kinds:

* ``payload``: attach (True) or release (False) the 15.65 lb plate at the
  tip; the modes and the static load jump, the links ring about their new
  equilibrium;
* ``seed``: restart the sensor-noise generators;
* ``adc_bits``: change the A/D resolution (12, 16, 20 bits).
"""

from __future__ import annotations

import heapq
from collections.abc import Iterable
from typing import Any, Literal, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["PendingCommands", "Scenario", "ScenarioEvent", "ScenarioTarget", "apply_event"]


class ScenarioTarget(Protocol):
    """What a scenario acts on (a :class:`plant_emulator.model.RalfArm`)."""

    @property
    def time_s(self) -> float: ...

    def advance(self, dt: float) -> None: ...

    def attach_payload(self, attached: bool) -> None: ...

    def reseed(self, seed: int) -> None: ...

    def set_adc_bits(self, bits: int) -> None: ...


class ScenarioEvent(BaseModel):
    """One scenario input at ``at_time_s`` (simulated seconds)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    at_time_s: float = Field(0.0, ge=0.0)
    kind: Literal["payload", "seed", "adc_bits"]
    payload_attached: bool | None = None
    seed: int | None = Field(None, ge=0)
    adc_bits: int | None = Field(None, ge=8, le=24)

    @model_validator(mode="after")
    def _value_present(self) -> ScenarioEvent:
        value = {"payload": self.payload_attached, "seed": self.seed, "adc_bits": self.adc_bits}[self.kind]
        if value is None:
            raise ValueError(f"a {self.kind!r} event needs its value")
        return self

    @classmethod
    def from_command(cls, cmd: Any) -> ScenarioEvent:
        """From a ``protocol.messages.ScenarioCommand`` (same fields, ``at_sim_time_s``)."""
        return cls(
            at_time_s=float(cmd.at_sim_time_s),
            kind=cmd.kind,
            payload_attached=cmd.payload_attached,
            seed=cmd.seed,
            adc_bits=cmd.adc_bits,
        )

    @classmethod
    def payload(cls, at_time_s: float, attached: bool) -> ScenarioEvent:
        return cls(at_time_s=at_time_s, kind="payload", payload_attached=attached)

    @classmethod
    def reseed(cls, at_time_s: float, seed: int) -> ScenarioEvent:
        return cls(at_time_s=at_time_s, kind="seed", seed=seed)

    @classmethod
    def resolution(cls, at_time_s: float, bits: int) -> ScenarioEvent:
        return cls(at_time_s=at_time_s, kind="adc_bits", adc_bits=bits)


def apply_event(target: ScenarioTarget, event: ScenarioEvent) -> None:
    """Apply one event now, whatever its time."""
    if event.kind == "payload":
        target.attach_payload(bool(event.payload_attached))
    elif event.kind == "seed":
        target.reseed(int(event.seed or 0))
    else:
        target.set_adc_bits(int(event.adc_bits or 12))


class Scenario:
    """Timed events, applied in time order (ties in the order given)."""

    def __init__(self, events: Iterable[ScenarioEvent] = ()) -> None:
        indexed = list(enumerate(events))
        indexed.sort(key=lambda ie: (ie[1].at_time_s, ie[0]))
        self.pending: list[ScenarioEvent] = [e for _, e in indexed]
        self.applied: list[tuple[float, ScenarioEvent]] = []
        """(simulated time when applied, event)."""

    def add(self, event: ScenarioEvent) -> None:
        self.pending.append(event)
        self.pending.sort(key=lambda e: e.at_time_s)

    def apply_due(self, target: ScenarioTarget) -> list[ScenarioEvent]:
        """Apply every pending event whose time has come (``<= target.time_s``)."""
        done: list[ScenarioEvent] = []
        while self.pending and self.pending[0].at_time_s <= target.time_s + 1e-9:
            ev = self.pending.pop(0)
            apply_event(target, ev)
            self.applied.append((target.time_s, ev))
            done.append(ev)
        return done

    def advance(self, target: ScenarioTarget, dt: float) -> list[ScenarioEvent]:
        """Advance ``target`` by ``dt``, stopping at each event in between to apply it."""
        if dt < 0:
            raise ValueError("dt must be >= 0")
        end = target.time_s + dt
        done = self.apply_due(target)
        while self.pending and self.pending[0].at_time_s <= end + 1e-9:
            step = self.pending[0].at_time_s - target.time_s
            if step > 0:
                target.advance(step)
            done += self.apply_due(target)
            if step <= 0 and not done:
                break
        rest = end - target.time_s
        if rest > 0:
            target.advance(rest)
        return done


class PendingCommands:
    """Scenario commands waiting for their simulated time, at most
    ``capacity`` of them: one more is dropped and counted (``dropped``).
    Kept in time order (ties: seq, then arrival), so asking what is due
    looks at the earliest only: a tick with nothing due costs one comparison,
    however many wait."""

    def __init__(self, capacity: int = 64) -> None:
        self.capacity = capacity
        self._heap: list[tuple[float, int, int, Any]] = []
        self._arrivals = 0
        self.dropped = 0

    def add(self, cmd: Any) -> bool:
        """Keep a command (anything with ``at_sim_time_s`` and ``seq``); False if full."""
        if len(self._heap) >= self.capacity:
            self.dropped += 1
            return False
        heapq.heappush(self._heap, (float(cmd.at_sim_time_s), int(cmd.seq), self._arrivals, cmd))
        self._arrivals += 1
        return True

    def due(self, now_s: float) -> list[Any]:
        """The commands whose time has come (``<= now_s``), in time order, removed."""
        out: list[Any] = []
        while self._heap and self._heap[0][0] <= now_s + 1e-12:
            out.append(heapq.heappop(self._heap)[3])
        return out

    def __len__(self) -> int:
        return len(self._heap)
