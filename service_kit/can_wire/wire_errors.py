"""Error frames and fault confinement on the ``ralfwire`` wire
(:mod:`service_kit.can_wire.wire_bus`): each bus of a channel is a node with
its own counters, and an attempt destroyed by an injected error (or an ACK
error) costs the bits :func:`service_kit.can_wire.arbitration.simulate`
gives it.

The rules and constants are the bus model's: :mod:`~service_kit.can_wire.error_state`
(CAN 2.0 part B section 8 / ISO 11898-1 fault confinement, rules 1-3 and 7-12)
and :class:`~service_kit.can_wire.arbitration.ErrorInjection` for which
attempts fail. A node's error state changes at the times the bus model
gives (:attr:`WireNode.changes`); :meth:`WireNode.status_at` reads it at
any moment, so a node learns its state only once the wire's clock has
reached the change.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import can

from service_kit.can_wire.arbitration import INTERMISSION_BITS, ErrorInjection, StateChange
from service_kit.can_wire.bits import FrameBits
from service_kit.can_wire.error_state import ERROR_DELIMITER_BITS, ERROR_FLAG_BITS, ErrorState, FaultConfinement


@dataclass(frozen=True)
class ErrorStatus:
    """A node's fault confinement at one moment."""

    state: ErrorState
    tec: int
    rec: int


ACTIVE_STATUS = ErrorStatus(ErrorState.ACTIVE, 0, 0)


@dataclass
class WireNode:
    """One ``ralfwire`` bus as a CAN node: its counters and their timeline."""

    name: str
    fc: FaultConfinement = field(default_factory=FaultConfinement)
    suspend_until_ns: int = 0
    """An error-passive transmitter's suspend transmission: it may not start before this."""
    changes: list[StateChange] = field(default_factory=list)
    """Every change of state or counters, in time order, as :attr:`BusRun.state_changes <service_kit.can_wire.arbitration.BusRun.state_changes>`."""
    _last: ErrorStatus = ACTIVE_STATUS

    def note(self, time_ns: int) -> None:
        """Records the counters as they are now, at ``time_ns``, if they changed."""
        now = ErrorStatus(self.fc.state, self.fc.tec, self.fc.rec)
        if now != self._last:
            self._last = now
            self.changes.append(StateChange(time_ns, self.name, now.state, now.tec, now.rec))

    def status_at(self, t_ns: int) -> ErrorStatus:
        """The state and counters in force at ``t_ns`` (the last change at or before it)."""
        for c in reversed(self.changes):  # a node's changes are in time order; the newest is the usual answer
            if c.time_ns <= t_ns:
                return ErrorStatus(c.state, c.tec, c.rec)
        return ACTIVE_STATUS


@dataclass(frozen=True)
class ErrorAttempt:
    """The bits of an attempt cut by an error frame: what the bus carried, in order."""

    sent: list[int]
    """The frame's bits up to the one before the error flag."""
    flag: list[int]
    """The error flag and the other nodes' flags superposed on it."""
    tail: list[int]
    """The error delimiter and the intermission: recessive."""

    @property
    def n_bits(self) -> int:
        return len(self.sent) + len(self.flag) + len(self.tail)


def error_attempt(frame: FrameBits, injected: ErrorInjection | None, passive_after: bool) -> ErrorAttempt:
    """The bits of a failed attempt, as :func:`~service_kit.can_wire.arbitration.simulate`
    lays them: the frame up to the injection's bit (or, without an injection,
    an ACK error: up to the ACK slot, left recessive), a 6-bit error flag plus
    ``echo_bits``, the 8-bit delimiter and the 3-bit intermission.
    ``passive_after``: the transmitter is error passive after counting this
    error; with an ACK error its flag is then passive (recessive), as nobody
    else makes it dominant."""
    if injected is not None:
        last, echo = injected.last_bit(frame), injected.echo_bits
    else:
        last, echo = frame.ack_slot_index, 0
    sent = list(frame.bits[: last + 1])
    if injected is None:
        sent[-1] = 1
    flag_bit = 1 if injected is None and passive_after else 0
    return ErrorAttempt(sent, [flag_bit] * (ERROR_FLAG_BITS + echo), [1] * (ERROR_DELIMITER_BITS + INTERMISSION_BITS))


def monitor_error_attempt(nodes: Sequence[WireNode], was_bus_off: set[str], attempt: ErrorAttempt, start_ns: int, bit_ns: int) -> None:
    """Rule 12 over an error attempt: nodes bus off before it count all its
    bits; a node it took bus off counts from its delimiter on (as the bus model)."""
    end_ns = start_ns + attempt.n_bits * bit_ns
    for n in nodes:
        if n.name in was_bus_off:
            done = n.fc.monitor(attempt.sent + attempt.flag + attempt.tail)
            if done is not None:
                n.note(start_ns + done * bit_ns)
        elif n.fc.bus_off:
            done = n.fc.monitor(attempt.tail)
            if done is not None:
                n.note(end_ns - len(attempt.tail) * bit_ns + done * bit_ns)


def error_state_reader(bus: can.BusABC) -> Callable[[], ErrorState] | None:
    """How to read ``bus``'s own CAN error state, if its class can tell it (a
    ``can_error_state`` property, as :class:`service_kit.can_wire.wire_bus.WireBus`'s,
    like a CAN controller's status register); None for any other bus."""
    if not isinstance(getattr(type(bus), "can_error_state", None), property):
        return None
    return lambda: bus.can_error_state  # type: ignore[attr-defined]
