"""python-can interface ``ralfwire``: the in-process ``virtual`` bus with a wire.

``can.Bus(interface="ralfwire", channel="rig", bitrate=500000)`` behaves like
python-can's ``virtual`` bus on that channel (every bus of the process on the
channel receives what the others send), except that a frame reaches the
other buses only when it would have finished on a real CAN bus:

- each :meth:`WireBus.send` hands the frame to the channel's :class:`Wire`
  at the clock's current time (the send returns at once, as with a CAN
  controller's transmit buffer); nobody needs to acknowledge it (a lone bus
  gets no ACK error here);
- whenever the wire is idle, the pending frames of all the channel's
  ``ralfwire`` buses arbitrate bitwise (the lowest arbitration field wins,
  :attr:`~service_kit.can_wire.bits.FrameBits.arbitration_key`); the winner
  occupies the wire for its exact bits (:mod:`service_kit.can_wire.bits`,
  stuff bits and intermission included) and is delivered, stamped with the
  time of its last EOF bit, to the other buses (and to itself with
  ``receive_own_messages``) at that moment; the others wait and contend again.

This is the same rule as :func:`service_kit.can_wire.arbitration.simulate`
(tested: the same inputs give the same delivery times).

Errors (off unless injected): :meth:`Wire.inject_errors` (or the bus's
``can_errors=[ErrorInjection(...)]``) destroys attempts as the bus model's
:class:`~service_kit.can_wire.arbitration.ErrorInjection` says (by
identifier, sender, time window on the wire's clock, every n-th, seeded
probability, count). A destroyed attempt costs the bus model's bits (frame
so far, error flag and echo, delimiter, intermission) and the frame contends
again. Each bus of the channel is a node (``node=`` name) with its own
counters (:mod:`service_kit.can_wire.error_state`, via
:mod:`service_kit.can_wire.wire_errors`): :meth:`WireBus.error_status` and
:attr:`WireBus.can_error_state` read them at the clock's now. A frame nobody
else acknowledges gets an ACK error only while errors are injected (without
them a lone bus gets no ACK error, as before). A bus-off node's
:meth:`WireBus.send` raises ``CanOperationError``; the frame it was sending
when it went bus off stays queued and goes out after its recovery (128 x 11
recessive bits), as a CAN controller's transmit buffer would.

Clocks: :class:`RealTimeWireClock` (the default) waits in a thread of the
wire for each frame's end on ``time.monotonic_ns``; the frame is delivered no
earlier than its wire time, later by however long the host takes to wake
the thread. :class:`ManualWireClock` moves only when its owner calls
:meth:`ManualWireClock.advance_to`, which delivers every frame that has
ended by then: deterministic, for tests and co-simulation.

Limitations: the wire joins the buses of one process only (python-can's
``virtual`` bus is in-process); frames sent from another process, or by a
plain ``virtual`` bus on the same channel (which still receives the wire's
frames), take no wire time and do not arbitrate. Errors are injected, not
detected: the wire makes no stuff, form or CRC errors of its own, and every
receiver sees every error (the bus model's limits). CAN FD and error frames
are refused by :meth:`WireBus.send`
(``CanOperationError``).
"""

from __future__ import annotations

import copy
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import can
from can.interfaces.virtual import VirtualBus

from service_kit.can_wire.arbitration import INTERMISSION_BITS, ErrorInjection, Injector
from service_kit.can_wire.bits import FrameBits, frame_of_message
from service_kit.can_wire.error_state import SUSPEND_BITS, ErrorState
from service_kit.can_wire.timing import bit_time_ns
from service_kit.can_wire.wire_errors import ErrorStatus, WireNode, error_attempt, monitor_error_attempt


class WireClock(Protocol):
    def now_ns(self) -> int: ...

    def timestamp(self, t_ns: int) -> float:
        """python-can timestamp (seconds) of the moment ``t_ns`` on this clock's axis."""
        ...


class RealTimeWireClock:
    """``time.monotonic_ns``; timestamps on ``time.time``'s axis, as python-can's."""

    realtime = True

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def timestamp(self, t_ns: int) -> float:
        return time.time() - (time.monotonic_ns() - t_ns) / 1e9


class ManualWireClock:
    """A clock that moves only by :meth:`advance_to`; timestamps are its nanoseconds in seconds.

    Sends at one time all contend: the wire decides what starts at time ``s``
    once the clock has moved past ``s`` (so every frame sent at ``s``, before
    or after the previous frame's end was delivered, takes part), which is
    why :meth:`next_event_ns` gives ``s + 1`` for a pending start."""

    realtime = False

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns
        self._wires: list[Wire] = []

    def now_ns(self) -> int:
        return self._now

    def timestamp(self, t_ns: int) -> float:
        return t_ns / 1e9

    def advance_to(self, t_ns: int) -> None:
        """Moves the clock to ``t_ns`` and delivers every frame that has ended by then."""
        if t_ns < self._now:
            raise ValueError(f"the clock cannot go back from {self._now} to {t_ns} ns")
        self._now = t_ns
        for wire in list(self._wires):
            wire.pump()

    def next_event_ns(self) -> int | None:
        """The earliest time at which one of the clock's wires has something to do."""
        times = [t for w in self._wires if (t := w.next_event_ns()) is not None]
        return min(times) if times else None

    def run(self, each: Callable[[], None], until_ns: int | None = None) -> None:
        """Calls ``each`` (the nodes' work: read, answer, send) now and after every
        move of the clock from one wire event to the next, until the wires have
        nothing left to do or the next event is past ``until_ns``."""
        while True:
            each()
            t = self.next_event_ns()
            if t is None or (until_ns is not None and t > until_ns):
                return
            self.advance_to(t)


@dataclass
class _Pending:
    queued_ns: int
    seq: int
    sender: VirtualBus
    msg: can.Message
    frame: FrameBits
    node: WireNode


@dataclass
class _InFlight:
    item: _Pending
    start_ns: int
    last_bit_ns: int
    end_ns: int
    ok: bool = True
    """False for an attempt cut by an error frame: nothing is delivered, the frame contends again."""


@dataclass
class Delivery:
    """A frame the wire delivered (kept in :attr:`Wire.log` when ``keep_log``)."""

    arbitration_id: int
    queued_ns: int
    start_ns: int
    last_bit_ns: int
    end_ns: int
    attempts: int = 1
    """Attempts it took (more than 1 after error frames)."""


@dataclass
class Wire:
    """One channel's wire (module docstring); shared by the channel's buses."""

    channel: Any
    bitrate: int
    clock: Any
    keep_log: bool = False
    fifo_per_sender: bool = False
    """True: each sender offers its oldest pending frame (a transmit FIFO, as a SocketCAN
    host's queue); False: its highest-priority one (priority-ordered transmit buffers).
    A sender with a ``fifo`` attribute chooses for itself."""
    log: list[Delivery] = field(default_factory=list)
    dropped: int = 0
    """Frames of a bus shut down before they went on the wire or while on it."""
    error_frames: int = 0
    """Attempts cut by an error frame (injected, or an ACK error while errors are on)."""
    nodes: list[WireNode] = field(default_factory=list)
    """The channel's buses as CAN nodes (fault confinement), in the order they opened."""
    _pending: list[_Pending] = field(default_factory=list)
    _in_flight: _InFlight | None = None
    _bus_free_ns: int = 0
    _seq: int = 0
    _users: int = 0
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _thread: threading.Thread | None = None
    _closed: bool = False
    _injectors: list[Injector] = field(default_factory=list)
    _attempts: dict[int, int] = field(default_factory=dict)
    _node_count: int = 0

    def __post_init__(self) -> None:
        self._bit = bit_time_ns(self.bitrate)
        if getattr(self.clock, "realtime", True):
            self._thread = threading.Thread(target=self._run, name=f"ralfwire-{self.channel}", daemon=True)
            self._thread.start()
        else:
            self.clock._wires.append(self)

    @property
    def errors_on(self) -> bool:
        """Whether error injection is on (:meth:`inject_errors`): only then are ACK errors made."""
        return bool(self._injectors)

    def inject_errors(self, *specs: ErrorInjection) -> None:
        """Adds error injections (module docstring, *Errors*); their counts and
        random draws start afresh here, their time windows are on the wire's clock."""
        with self._cond:
            self._injectors.extend(Injector(s) for s in specs)
            self._cond.notify()

    def add_node(self, name: str) -> WireNode:
        with self._cond:
            if any(n.name == name for n in self.nodes):
                raise can.CanInitializationError(f"channel {self.channel!r} already has a node named {name!r}")
            node = WireNode(name)
            self.nodes.append(node)
            return node

    def remove_node(self, node: WireNode) -> None:
        with self._cond:
            if node in self.nodes:
                self.nodes.remove(node)

    def submit(self, sender: VirtualBus, msg: can.Message, frame: FrameBits, node: WireNode) -> None:
        with self._cond:
            self._seq += 1
            self._pending.append(_Pending(self.clock.now_ns(), self._seq, sender, msg, frame, node))
            self._cond.notify()

    def queued_ids(self) -> list[int]:
        """The identifiers of the frames waiting for the wire (not yet delivered), in the order they were sent."""
        with self._cond:
            return [p.frame.arbitration_id for p in self._pending]

    def status(self, node: WireNode) -> ErrorStatus:
        """``node``'s error state and counters at the clock's now."""
        with self._cond:
            return node.status_at(self.clock.now_ns())

    def next_event_ns(self) -> int | None:
        with self._cond:
            if self._in_flight is not None:
                return self._in_flight.last_bit_ns
            wake = self._wake(self._bus_free_ns)
            if wake is None:
                return None
            return wake + 1  # a start at s is decided once the clock has passed s

    def _wake(self, bus_free: int) -> int | None:
        """When the next attempt may start (or, for a node waiting out its
        suspension or bus-off recovery, when the wire must look again)."""
        if any(self._ready(p, bus_free) for p in self._pending):
            return bus_free
        times = self._wake_times(bus_free)
        return max(min(times), bus_free) if times else None

    def _ready(self, p: _Pending, bus_free: int) -> bool:
        return p.queued_ns <= bus_free and not p.node.fc.bus_off and p.node.suspend_until_ns <= bus_free

    def _wake_times(self, bus_free: int) -> list[int]:
        """The bus model's wake-up times: the next arrival, and per node with
        frames waiting its recovery or the end of its suspension."""
        times = [min(p.queued_ns for p in later)] if (later := [p for p in self._pending if p.queued_ns > bus_free]) else []
        for node in {id(p.node): p.node for p in self._pending if p.queued_ns <= bus_free}.values():
            to_recover = node.fc.idle_bits_to_recover()
            times.append(bus_free + to_recover * self._bit if to_recover is not None else node.suspend_until_ns)
        return times

    def pump(self) -> None:
        """Delivers what has ended and starts what may start, up to the clock's now
        (the steps of :func:`~service_kit.can_wire.arbitration.simulate`)."""
        now = self.clock.now_ns()
        with self._cond:
            while True:
                flight = self._in_flight
                if flight is not None:
                    if flight.last_bit_ns > now:
                        return
                    if flight.ok:
                        self._deliver(flight)
                    self._bus_free_ns = flight.end_ns
                    self._in_flight = None
                self._pending = [p for p in self._pending if self._alive(p)]
                if not self._pending:
                    return
                bus_free = self._bus_free_ns
                ready = [p for p in self._pending if self._ready(p, bus_free)]
                if not ready:
                    times = self._wake_times(bus_free)
                    t = max(min(times), bus_free)
                    if t > now:  # later sends queue at now or after: the idle bus up to now is known
                        return
                    self._idle(bus_free, t)
                    self._bus_free_ns = t
                    continue
                if bus_free >= now:  # a frame handed over at ``start`` itself may still contend
                    return
                contenders: list[_Pending] = []
                heads: set[int] = set()
                for p in ready:  # in submission order: a FIFO sender's first is its oldest
                    if getattr(p.sender, "fifo", self.fifo_per_sender):
                        if id(p.sender) in heads:
                            continue
                        heads.add(id(p.sender))
                    contenders.append(p)
                winner = min(contenders, key=lambda p: (p.frame.arbitration_key, p.queued_ns, p.seq))
                self._in_flight = self._attempt(winner, bus_free)

    def _idle(self, from_ns: int, to_ns: int) -> None:
        n_bits = (to_ns - from_ns) // self._bit
        for node in self.nodes:
            done = node.fc.monitor_idle(n_bits)
            if done is not None:
                node.note(from_ns + done * self._bit)

    def _attempt(self, item: _Pending, start: int) -> _InFlight:
        """One use of the wire by ``item`` from ``start``: its counters, and whether it gets through."""
        bit = self._bit
        frame = item.frame
        tx = item.node
        self._attempts[item.seq] = self._attempts.get(item.seq, 0) + 1
        receivers = [n for n in self.nodes if n is not tx and not n.fc.bus_off]
        injected = next((i.spec for i in self._injectors if i.fires(tx.name, frame, start, self._attempts[item.seq])), None)
        ack_error = injected is None and not receivers and self.errors_on
        if injected is None and not ack_error:
            self._pending.remove(item)
            end = start + frame.n_bits * bit
            tx.fc.transmit_success()
            for n in receivers:
                n.fc.receive_success()
            for n in self.nodes:
                if n is not tx:
                    done = n.fc.monitor(frame.bits)
                    if done is not None:
                        n.note(start + done * bit)
            flight = _InFlight(item, start, end - INTERMISSION_BITS * bit, end)
        else:
            self.error_frames += 1
            was_bus_off = {n.name for n in self.nodes if n.fc.bus_off}
            tx.fc.transmit_error(ack_error=ack_error, dominant_during_passive_flag=False)
            for n in receivers:
                n.fc.receive_error()
            attempt = error_attempt(frame, injected, tx.fc.state is ErrorState.PASSIVE)
            for n in self.nodes:
                n.note(start + len(attempt.sent) * bit)
            end = start + attempt.n_bits * bit
            monitor_error_attempt(self.nodes, was_bus_off, attempt, start, bit)
            flight = _InFlight(item, start, end, end, ok=False)
        for n in self.nodes:
            n.note(end)
        if tx.fc.state is ErrorState.PASSIVE:
            tx.suspend_until_ns = end + SUSPEND_BITS * bit
        return flight

    def _alive(self, p: _Pending) -> bool:
        if getattr(p.sender, "_open", True):
            return True
        self.dropped += 1
        self._attempts.pop(p.seq, None)
        return False

    def _deliver(self, flight: _InFlight) -> None:
        item = flight.item
        if self.keep_log:
            self.log.append(
                Delivery(item.frame.arbitration_id, item.queued_ns, flight.start_ns, flight.last_bit_ns, flight.end_ns, self._attempts.get(item.seq, 1))
            )
        self._attempts.pop(item.seq, None)
        if not getattr(item.sender, "_open", True):
            self.dropped += 1
            return
        msg = copy.copy(item.msg)
        msg.timestamp = self.clock.timestamp(flight.last_bit_ns)
        try:
            item.sender.send(msg)
        except can.CanOperationError:  # the sender closed while its frame was on the wire
            self.dropped += 1

    def _run(self) -> None:
        while True:
            self.pump()
            with self._cond:
                if self._closed:
                    return
                nxt = self.next_event_ns()
                now = self.clock.now_ns()
                if nxt is None:
                    self._cond.wait()
                elif nxt > now:
                    self._cond.wait((nxt - now) / 1e9)

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        if self._thread is not None:
            self._thread.join(timeout=5)
        elif self in self.clock._wires:
            self.clock._wires.remove(self)


_wires: dict[Any, Wire] = {}
_wires_lock = threading.Lock()


def wire_of(channel: Any) -> Wire | None:
    """The channel's wire while a ``ralfwire`` bus is open on it."""
    with _wires_lock:
        return _wires.get(channel)


class WireBus(can.BusABC):
    """The ``ralfwire`` interface (module docstring). ``channel`` any hashable
    (python-can's ``virtual`` channels); ``bitrate`` bit/s (every bus of a
    channel must give the same); ``clock`` a :class:`ManualWireClock` for
    deterministic use (default real time; every bus of a channel shares the
    first one's); ``keep_log`` keeps each delivery's times in
    :attr:`Wire.log`."""

    def __init__(
        self,
        channel: Any = "ralfwire",
        bitrate: int = 500_000,
        receive_own_messages: bool = False,
        clock: Any = None,
        keep_log: bool = False,
        node: str | None = None,
        can_errors: Sequence[ErrorInjection] = (),
        **kwargs: Any,
    ) -> None:
        self._is_shutdown = True  # until opened: a refused bus has nothing to shut down
        try:
            bit_time_ns(int(bitrate))
        except ValueError as exc:
            raise can.CanInitializationError(str(exc)) from exc
        with _wires_lock:
            wire = _wires.get(channel)
            if wire is None:
                wire = Wire(channel, int(bitrate), clock if clock is not None else RealTimeWireClock(), keep_log=keep_log)
                _wires[channel] = wire
            elif wire.bitrate != int(bitrate):
                raise can.CanInitializationError(f"channel {channel!r} runs at {wire.bitrate} bit/s, not {bitrate}")
            elif clock is not None and clock is not wire.clock:
                raise can.CanInitializationError(f"channel {channel!r} already runs on another clock")
            wire._users += 1
            wire._node_count += 1
            count = wire._node_count
        self._wire = wire
        try:
            self._node = wire.add_node(node if node is not None else f"bus{count}")
        except can.CanInitializationError:
            self._release_wire()
            raise
        if can_errors:
            wire.inject_errors(*can_errors)
        self._virtual = VirtualBus(channel=channel, receive_own_messages=receive_own_messages, preserve_timestamps=True)
        self.channel_info = f"ralfwire channel {channel!r} at {wire.bitrate} bit/s (in-process virtual bus with wire time)"
        super().__init__(channel=channel, **kwargs)
        self._is_shutdown = False

    @property
    def wire(self) -> Wire:
        return self._wire

    @property
    def node(self) -> WireNode:
        """This bus as a CAN node on the wire: its counters and their timeline."""
        return self._node

    def error_status(self) -> ErrorStatus:
        """This node's error state, TEC and REC at the wire clock's now."""
        return self._wire.status(self._node)

    @property
    def can_error_state(self) -> ErrorState:
        """This node's error state now (error active, error passive, bus off):
        what a CAN controller's status register tells its host."""
        return self.error_status().state

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            frame = frame_of_message(msg)
        except ValueError as exc:
            raise can.CanOperationError(f"ralfwire cannot send this frame: {exc}") from exc
        if self.can_error_state is ErrorState.BUS_OFF:
            raise can.CanOperationError(f"ralfwire node {self._node.name!r} is bus off: it sends nothing until it has recovered")
        self._wire.submit(self._virtual, msg, frame, self._node)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._virtual._recv_internal(timeout)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._virtual.shutdown()
        self._wire.remove_node(self._node)
        self._release_wire()

    def _release_wire(self) -> None:
        with _wires_lock:
            self._wire._users -= 1
            last = self._wire._users == 0
            if last and _wires.get(self._wire.channel) is self._wire:
                del _wires[self._wire.channel]
        if last:
            self._wire.close()
