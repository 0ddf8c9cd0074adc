"""A deterministic discrete-event CAN bus: bitwise arbitration, wire time,
error frames with automatic retransmission, and fault confinement.

:func:`simulate` takes the frames nodes queue at simulated times (integer
nanoseconds) and returns when each went on the wire:

- The bus is idle until a frame is queued; the frame's SOF starts at once.
- Whenever the bus becomes idle (after a frame's 3-bit intermission) every
  node offers its own highest-priority pending frame queued by then (a
  controller with priority-ordered transmit buffers, as Davis et al.'s
  analysis assumes); the lowest :attr:`~service_kit.can_wire.bits.FrameBits.arbitration_key`
  wins (ISO 11898-1 bitwise arbitration: dominant 0 overwrites recessive 1,
  so the lower identifier, a data frame before a remote frame of the same
  identifier, a standard frame before an extended one of the same base
  identifier). The others wait and contend again at the next idle moment.
- A frame occupies the bus for its exact bits
  (:attr:`~service_kit.can_wire.bits.FrameBits.n_bits`, intermission
  included). A frame nobody else on the bus can acknowledge (no other node,
  or all others bus off) gets an ACK error; an injected error
  (:class:`ErrorInjection`) destroys the attempt at a chosen bit. Either way
  the bus carries the bits sent so far, a 6-bit error flag, 0..6 bits of
  other nodes' flags, the 8-bit error delimiter and the intermission, and
  the frame contends again (automatic retransmission).
- Fault confinement (:mod:`service_kit.can_wire.error_state`): the
  transmitter's TEC +8 on an error (-1 on success), each receiver's REC +1
  on an error (-1 on success); an error-passive transmitter waits 8 more
  bits (suspend transmission) before it may start again; a bus-off node
  neither sends nor acknowledges, keeps its pending frames and recovers
  after 128 occurrences of 11 recessive bits on the bus.

Two frames with the same arbitration field from two nodes would both win
arbitration and collide in the data field on a real bus; here the one
queued first wins and :attr:`BusRun.id_collisions` counts the occasions.
"""

from __future__ import annotations

import random
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from service_kit.can_wire.bits import FrameBits
from service_kit.can_wire.error_state import (
    ERROR_DELIMITER_BITS,
    ERROR_ECHO_MAX,
    ERROR_FLAG_BITS,
    SUSPEND_BITS,
    ErrorState,
    FaultConfinement,
)
from service_kit.can_wire.timing import bit_time_ns

INTERMISSION_BITS = 3


@dataclass(frozen=True)
class QueuedFrame:
    """A frame node ``node`` hands its controller at ``queued_ns``."""

    node: str
    queued_ns: int
    frame: FrameBits


@dataclass(frozen=True)
class ErrorInjection:
    """Destroys attempts on the wire: those of ``arbitration_id`` (any if
    None) sent by ``node`` (any if None) starting in ``[start_ns, end_ns)``;
    of those, every ``every``-th, each with ``probability`` (a
    ``random.Random(seed)`` draw, so a run is repeatable); at most ``count``
    errors (None: no limit). ``bit`` is the index in the frame's bits of the
    last bit sent before the error flag (default: the ACK delimiter, where a
    CRC error is signalled); ``echo_bits`` (0..6) are other nodes' flags
    superposed on the first. ``first_attempts``: only a frame's first so
    many attempts can fail (None: any), so with ``count=None`` every frame
    of the identifier fails that many times and then goes through. The
    counts start afresh in every :func:`simulate` call."""

    arbitration_id: int | None = None
    node: str | None = None
    start_ns: int = 0
    end_ns: int | None = None
    every: int = 1
    probability: float = 1.0
    seed: int = 0
    count: int | None = 1
    bit: int | None = None
    echo_bits: int = 0
    first_attempts: int | None = None

    def __post_init__(self) -> None:
        if self.first_attempts is not None and self.first_attempts < 1:
            raise ValueError(f"first_attempts must be >= 1, got {self.first_attempts}")
        if self.every < 1:
            raise ValueError(f"every must be >= 1, got {self.every}")
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability must be 0..1, got {self.probability}")
        if not 0 <= self.echo_bits <= ERROR_ECHO_MAX:
            raise ValueError(f"echo_bits must be 0..{ERROR_ECHO_MAX}, got {self.echo_bits}")

    def matches(self, node: str, frame: FrameBits, start_ns: int) -> bool:
        if self.arbitration_id is not None and frame.arbitration_id != self.arbitration_id:
            return False
        if self.node is not None and node != self.node:
            return False
        return start_ns >= self.start_ns and (self.end_ns is None or start_ns < self.end_ns)

    def last_bit(self, frame: FrameBits) -> int:
        bit = frame.ack_delimiter_index if self.bit is None else self.bit
        if not 0 <= bit < frame.n_bits_to_eof:
            raise ValueError(f"error bit {bit} outside the frame (0..{frame.n_bits_to_eof - 1})")
        return bit


class Injector:
    """One run's state of an :class:`ErrorInjection`: attempts matched, errors made, its random draws."""

    def __init__(self, spec: ErrorInjection) -> None:
        self.spec = spec
        self.seen = 0
        self.fired = 0
        self.rng = random.Random(spec.seed)

    def fires(self, node: str, frame: FrameBits, start_ns: int, attempt: int = 1) -> bool:
        """Whether this attempt (the frame's ``attempt``-th) fails."""
        spec = self.spec
        if spec.count is not None and self.fired >= spec.count:
            return False
        if spec.first_attempts is not None and attempt > spec.first_attempts:
            return False
        if not spec.matches(node, frame, start_ns):
            return False
        self.seen += 1
        if self.seen % spec.every:
            return False
        if spec.probability < 1.0 and self.rng.random() >= spec.probability:
            return False
        self.fired += 1
        return True


@dataclass(frozen=True)
class Attempt:
    """One use of the bus: a frame that won arbitration, sent whole or cut by an error."""

    index: int
    """Index of the frame in :func:`simulate`'s input."""
    node: str
    arbitration_id: int
    start_ns: int
    end_ns: int
    """When the bus is idle again (after the intermission)."""
    ok: bool
    bits: int
    """Bits the attempt occupied the bus for (error frame included)."""
    losers: tuple[int, ...]
    """Frames (input indices) that lost arbitration to this one."""
    ack_error: bool = False


@dataclass(frozen=True)
class Transmission:
    """A frame sent successfully."""

    index: int
    node: str
    arbitration_id: int
    queued_ns: int
    start_ns: int
    """SOF of the successful attempt."""
    last_bit_ns: int
    """End of the last EOF bit."""
    end_ns: int
    """End of the intermission: the bus is free again."""
    attempts: int

    @property
    def queuing_delay_ns(self) -> int:
        return self.start_ns - self.queued_ns

    @property
    def response_ns(self) -> int:
        """Queued to bus free, as Davis et al.'s response time (whose C_m includes the intermission)."""
        return self.end_ns - self.queued_ns


@dataclass(frozen=True)
class StateChange:
    time_ns: int
    node: str
    state: ErrorState
    tec: int
    rec: int


@dataclass
class BusRun:
    """What :func:`simulate` saw."""

    bitrate: int
    transmissions: list[Transmission]
    attempts: list[Attempt]
    state_changes: list[StateChange]
    unsent: list[int]
    """Input indices still pending when the run ended."""
    counters: dict[str, FaultConfinement]
    id_collisions: int = 0


def simulate(
    frames: Sequence[QueuedFrame],
    bitrate: int,
    *,
    nodes: Iterable[str] = (),
    errors: Sequence[ErrorInjection] = (),
    until_ns: int | None = None,
    max_attempts: int = 1_000_000,
    rec_after_passive_success: int = 127,
) -> BusRun:
    """Runs the bus (module docstring). ``nodes`` adds nodes that only
    receive (and acknowledge); ``until_ns`` stops starting attempts at that
    time (needed when errors never stop: a lone error-passive transmitter
    retries for ever); more than ``max_attempts`` attempts raise ValueError."""
    bit = bit_time_ns(bitrate)
    injectors = [Injector(e) for e in errors]
    all_nodes = sorted({q.node for q in frames} | set(nodes))
    counters = {n: FaultConfinement(rec_after_passive_success=rec_after_passive_success) for n in all_nodes}
    suspend_until = dict.fromkeys(all_nodes, 0)
    arrivals = sorted(range(len(frames)), key=lambda i: (frames[i].queued_ns, i))
    next_arrival = 0
    pending: dict[str, list[int]] = {n: [] for n in all_nodes}
    attempts_of = [0] * len(frames)
    run = BusRun(bitrate=bitrate, transmissions=[], attempts=[], state_changes=[], unsent=[], counters=counters)
    last_state = {n: (ErrorState.ACTIVE, 0, 0) for n in all_nodes}

    def note(time_ns: int) -> None:
        for n in all_nodes:
            c = counters[n]
            now = (c.state, c.tec, c.rec)
            if now != last_state[n]:
                last_state[n] = now
                run.state_changes.append(StateChange(time_ns, n, c.state, c.tec, c.rec))

    def idle(from_ns: int, to_ns: int) -> None:
        """The bus idle (recessive) from ``from_ns`` to ``to_ns``: bus-off nodes count it."""
        n_bits = (to_ns - from_ns) // bit
        for n in all_nodes:
            done = counters[n].monitor_idle(n_bits)
            if done is not None:
                note(from_ns + done * bit)

    def seen(start_ns: int, bits: Sequence[int], skip: str | None = None) -> None:
        for n in all_nodes:
            if n == skip:
                continue
            done = counters[n].monitor(bits)
            if done is not None:
                note(start_ns + done * bit)

    bus_free = 0
    while True:
        while next_arrival < len(arrivals) and frames[arrivals[next_arrival]].queued_ns <= bus_free:
            i = arrivals[next_arrival]
            pending[frames[i].node].append(i)
            next_arrival += 1
        ready = [n for n in all_nodes if pending[n] and not counters[n].bus_off and suspend_until[n] <= bus_free]
        if not ready:
            wake: list[int] = []
            if next_arrival < len(arrivals):
                wake.append(frames[arrivals[next_arrival]].queued_ns)
            for n in all_nodes:
                if pending[n]:
                    to_recover = counters[n].idle_bits_to_recover()
                    wake.append(bus_free + to_recover * bit if to_recover is not None else suspend_until[n])
            if not wake:
                break
            t = max(min(wake), bus_free)
            if until_ns is not None and t >= until_ns:
                idle(bus_free, until_ns)
                break
            idle(bus_free, t)
            bus_free = t
            continue
        start = bus_free
        if until_ns is not None and start >= until_ns:
            break
        offers = [min(pending[n], key=lambda i: (frames[i].frame.arbitration_key, frames[i].queued_ns, i)) for n in ready]
        offers.sort(key=lambda i: (frames[i].frame.arbitration_key, frames[i].queued_ns, i))
        winner = offers[0]
        if len(offers) > 1 and frames[offers[1]].frame.arbitration_key == frames[winner].frame.arbitration_key:
            run.id_collisions += 1
        q = frames[winner]
        frame = q.frame
        tx = counters[q.node]
        receivers = [n for n in all_nodes if n != q.node and not counters[n].bus_off]
        attempts_of[winner] += 1
        if len(run.attempts) >= max_attempts:
            raise ValueError(f"more than {max_attempts} attempts on the bus: give until_ns or fewer errors")
        injected = next((e.spec for e in injectors if e.fires(q.node, frame, start, attempts_of[winner])), None)
        ack_error = injected is None and not receivers
        if injected is None and not ack_error:
            end = start + frame.n_bits * bit
            tx.transmit_success()
            for n in receivers:
                counters[n].receive_success()
            seen(start, frame.bits)
            pending[q.node].remove(winner)
            run.transmissions.append(
                Transmission(
                    index=winner,
                    node=q.node,
                    arbitration_id=frame.arbitration_id,
                    queued_ns=q.queued_ns,
                    start_ns=start,
                    last_bit_ns=end - INTERMISSION_BITS * bit,
                    end_ns=end,
                    attempts=attempts_of[winner],
                )
            )
            n_bits = frame.n_bits
        else:
            if injected is not None:
                last, echo = injected.last_bit(frame), injected.echo_bits
            else:
                last, echo = frame.ack_slot_index, 0
            sent = list(frame.bits[: last + 1])
            if ack_error:
                sent[-1] = 1  # nobody acknowledged: the ACK slot stays recessive
            flag_start = start + len(sent) * bit
            was_bus_off = {n for n in all_nodes if counters[n].bus_off}
            tx.transmit_error(ack_error=ack_error, dominant_during_passive_flag=False)
            for n in receivers:
                counters[n].receive_error()
            note(flag_start)
            n_bits = len(sent) + ERROR_FLAG_BITS + echo + ERROR_DELIMITER_BITS + INTERMISSION_BITS
            end = start + n_bits * bit
            flag = [0] * (ERROR_FLAG_BITS + echo)
            if ack_error and tx.state is ErrorState.PASSIVE:
                flag = [1] * (ERROR_FLAG_BITS + echo)  # a passive error flag, nobody else to make it dominant
            tail = [1] * (ERROR_DELIMITER_BITS + INTERMISSION_BITS)
            for n in all_nodes:
                if n in was_bus_off:
                    done = counters[n].monitor(sent + flag + tail)
                    if done is not None:
                        note(start + done * bit)
                elif counters[n].bus_off:  # went bus off with this error flag: counts from its end
                    done = counters[n].monitor(tail)
                    if done is not None:
                        note(end - len(tail) * bit + done * bit)
        run.attempts.append(
            Attempt(
                index=winner,
                node=q.node,
                arbitration_id=frame.arbitration_id,
                start_ns=start,
                end_ns=end,
                ok=injected is None and not ack_error,
                bits=n_bits,
                losers=tuple(offers[1:]),
                ack_error=ack_error,
            )
        )
        note(end)
        if tx.state is ErrorState.PASSIVE:
            suspend_until[q.node] = end + SUSPEND_BITS * bit
        bus_free = end
    run.unsent = sorted(i for n in all_nodes for i in pending[n]) + [arrivals[k] for k in range(next_arrival, len(arrivals))]
    return run
