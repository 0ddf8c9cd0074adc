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
without errors (tested: the same inputs give the same delivery times).

Clocks: :class:`RealTimeWireClock` (the default) waits in a thread of the
wire for each frame's end on ``time.monotonic_ns``; the frame is delivered no
earlier than its wire time, later by however long the host takes to wake
the thread. :class:`ManualWireClock` moves only when its owner calls
:meth:`ManualWireClock.advance_to`, which delivers every frame that has
ended by then: deterministic, for tests and co-simulation.

Limitations: the wire joins the buses of one process only (python-can's
``virtual`` bus is in-process); frames sent from another process, or by a
plain ``virtual`` bus on the same channel (which still receives the wire's
frames), take no wire time and do not arbitrate. No error frames, no fault
confinement (those are in :func:`~service_kit.can_wire.arbitration.simulate`).
CAN FD and error frames are refused by :meth:`WireBus.send`
(``CanOperationError``).
"""

from __future__ import annotations

import copy
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import can
from can.interfaces.virtual import VirtualBus

from service_kit.can_wire.bits import FrameBits, frame_of_message
from service_kit.can_wire.timing import bit_time_ns


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


@dataclass
class _Pending:
    queued_ns: int
    seq: int
    sender: VirtualBus
    msg: can.Message
    frame: FrameBits


@dataclass
class _InFlight:
    item: _Pending
    start_ns: int
    last_bit_ns: int
    end_ns: int


@dataclass
class Delivery:
    """A frame the wire delivered (kept in :attr:`Wire.log` when ``keep_log``)."""

    arbitration_id: int
    queued_ns: int
    start_ns: int
    last_bit_ns: int
    end_ns: int


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
    _pending: list[_Pending] = field(default_factory=list)
    _in_flight: _InFlight | None = None
    _bus_free_ns: int = 0
    _seq: int = 0
    _users: int = 0
    _cond: threading.Condition = field(default_factory=threading.Condition)
    _thread: threading.Thread | None = None
    _closed: bool = False

    def __post_init__(self) -> None:
        self._bit = bit_time_ns(self.bitrate)
        if getattr(self.clock, "realtime", True):
            self._thread = threading.Thread(target=self._run, name=f"ralfwire-{self.channel}", daemon=True)
            self._thread.start()
        else:
            self.clock._wires.append(self)

    def submit(self, sender: VirtualBus, msg: can.Message, frame: FrameBits) -> None:
        with self._cond:
            self._seq += 1
            self._pending.append(_Pending(self.clock.now_ns(), self._seq, sender, msg, frame))
            self._cond.notify()

    def next_event_ns(self) -> int | None:
        with self._cond:
            if self._in_flight is not None:
                return self._in_flight.last_bit_ns
            if self._pending:  # a start at s is decided once the clock has passed s
                return max(self._bus_free_ns, min(p.queued_ns for p in self._pending)) + 1
            return None

    def pump(self) -> None:
        """Delivers what has ended and starts what may start, up to the clock's now."""
        now = self.clock.now_ns()
        with self._cond:
            while True:
                flight = self._in_flight
                if flight is not None:
                    if flight.last_bit_ns > now:
                        return
                    self._deliver(flight)
                    self._bus_free_ns = flight.end_ns
                    self._in_flight = None
                self._pending = [p for p in self._pending if self._alive(p)]
                if not self._pending:
                    return
                start = max(self._bus_free_ns, min(p.queued_ns for p in self._pending))
                if start >= now:  # a frame handed over at ``start`` itself may still contend
                    return
                contenders = [p for p in self._pending if p.queued_ns <= start]
                kept: list[_Pending] = []
                heads: set[int] = set()
                for p in contenders:  # _pending is in submission order: a FIFO sender's first is its oldest
                    if getattr(p.sender, "fifo", self.fifo_per_sender):
                        if id(p.sender) in heads:
                            continue
                        heads.add(id(p.sender))
                    kept.append(p)
                contenders = kept
                winner = min(contenders, key=lambda p: (p.frame.arbitration_key, p.queued_ns, p.seq))
                self._pending.remove(winner)
                end = start + winner.frame.n_bits * self._bit
                self._in_flight = _InFlight(winner, start, end - 3 * self._bit, end)

    def _alive(self, p: _Pending) -> bool:
        if getattr(p.sender, "_open", True):
            return True
        self.dropped += 1
        return False

    def _deliver(self, flight: _InFlight) -> None:
        item = flight.item
        if self.keep_log:
            self.log.append(Delivery(item.frame.arbitration_id, item.queued_ns, flight.start_ns, flight.last_bit_ns, flight.end_ns))
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
        self._wire = wire
        self._virtual = VirtualBus(channel=channel, receive_own_messages=receive_own_messages, preserve_timestamps=True)
        self.channel_info = f"ralfwire channel {channel!r} at {wire.bitrate} bit/s (in-process virtual bus with wire time)"
        super().__init__(channel=channel, **kwargs)
        self._is_shutdown = False

    @property
    def wire(self) -> Wire:
        return self._wire

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        try:
            frame = frame_of_message(msg)
        except ValueError as exc:
            raise can.CanOperationError(f"ralfwire cannot send this frame: {exc}") from exc
        self._wire.submit(self._virtual, msg, frame)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._virtual._recv_internal(timeout)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._virtual.shutdown()
        with _wires_lock:
            self._wire._users -= 1
            last = self._wire._users == 0
            if last and _wires.get(self._wire.channel) is self._wire:
                del _wires[self._wire.channel]
        if last:
            self._wire.close()
