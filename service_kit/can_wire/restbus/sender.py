"""The restbus on a python-can bus (``virtual``, ``udp_multicast``,
``ralfwire``, or hardware): a sender that sends each instance of
:func:`service_kit.can_wire.restbus.traffic.schedule` when it is due.

The clock is injected: ``clock_ns()`` gives the time and ``wait_until(t_ns)``
waits for it (False: stop). By default they are ``time.monotonic_ns`` and
an event wait, so the sender runs in real time and a stop wakes it at once;
an instance more than half its cycle late (a slow host) is sent at once and counted in
:attr:`RestbusSender.late`. ``until_ns`` and ``max_frames`` bound a run.
Every frame sent is kept in :attr:`RestbusSender.sent` with the clock's
time at the send. A bus that refuses a frame (``can.CanError``) is counted
in :attr:`RestbusSender.send_errors`, with the last error's text.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import can

from service_kit.can_wire.restbus.traffic import Restbus, schedule


@dataclass(frozen=True)
class Sent:
    time_ns: int
    """The clock's time at the send (relative to the sender's start)."""
    name: str
    k: int
    msg: can.Message


class RestbusSender:
    """Sends ``restbus`` on ``bus`` (module docstring)."""

    def __init__(
        self,
        bus: can.BusABC,
        restbus: Restbus,
        *,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        wait_until: Callable[[int], bool] | None = None,
        until_ns: int | None = None,
        max_frames: int | None = None,
    ) -> None:
        if until_ns is None and max_frames is None and wait_until is not None:
            raise ValueError("an injected clock needs until_ns or max_frames")
        self.bus = bus
        self.restbus = restbus
        self.clock_ns = clock_ns
        self._stop = threading.Event()
        self.wait_until = wait_until if wait_until is not None else self._wait_real_time
        self.until_ns = until_ns
        self.max_frames = max_frames
        self.sent: list[Sent] = []
        self.late = 0
        self.send_errors = 0
        self.last_error = ""
        self._thread: threading.Thread | None = None

    def _wait_real_time(self, t_ns: int) -> bool:
        while True:
            left = t_ns - self.clock_ns()
            if left <= 0 or self._stop.is_set():
                return not self._stop.is_set()
            if self._stop.wait(left / 1e9):
                return False

    def run(self) -> int:
        """Sends until ``until_ns``, ``max_frames`` or :meth:`stop`; returns the frames sent."""
        start = self.clock_ns()
        horizon = self.until_ns if self.until_ns is not None else 1 << 62
        for inst in schedule(self.restbus.messages, horizon, start):
            if self.max_frames is not None and len(self.sent) + self.send_errors >= self.max_frames:
                break
            if self._stop.is_set() or not self.wait_until(inst.time_ns):
                break
            now = self.clock_ns()
            if now > inst.time_ns + inst.message.cycle_ns // 2:
                self.late += 1
            m = inst.message
            msg = can.Message(
                arbitration_id=m.frame_id,
                is_extended_id=m.extended,
                data=inst.payload(),
                timestamp=now / 1e9,
            )
            try:
                self.bus.send(msg)
            except can.CanError as exc:
                self.send_errors += 1
                self.last_error = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                continue
            self.sent.append(Sent(now - start, m.name, inst.k, msg))
        return len(self.sent)

    def start(self) -> None:
        """Runs :meth:`run` in a daemon thread."""
        self._thread = threading.Thread(target=self.run, name="restbus-sender", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        """The thread of :meth:`start` is still sending."""
        return self._thread is not None and self._thread.is_alive()

    def stop(self, timeout: float | None = 5.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
