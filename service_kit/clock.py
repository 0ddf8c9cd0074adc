"""One clock for the rig: the scheduler interface every board's loop runs on.

A core never reads ``time.monotonic()`` and never sleeps: it asks its
:class:`Scheduler` for ``now()`` and waits with :meth:`Scheduler.wait_until`
(or :meth:`Scheduler.wait`), which returns at once when the process is told
to stop. Two kinds of implementation:

* :class:`RealTimeScheduler`: the wall clock (``time.monotonic``); waiting
  sleeps until the deadline or until the stop event is set. The three
  processes of a real-time rig and the edges of a lockstep one use it
  (a lockstep run waits in *wall* time for the next frame of its handshake,
  never for a time on the simulated axis).
* :class:`LockstepScheduler`: wall time for the handshake's timeouts, but
  it never paces: waiting until a tick's time returns at once, because in
  lockstep the step boundary is the handshake itself (SYNC -> TPDO, a
  batch's interrupt at its due tick), never the wall clock.
* :class:`SimulatedScheduler`: a clock that only moves when its owner
  advances it (the co-simulation master: one sample period per tick).
  Waiting until a time in the future *is* advancing to it, so a due time
  (the DSP's emulated latency, a heartbeat) is reached without any wall
  time passing. Deterministic by construction.

Both count how often a wait was cut short by ``stop``.
"""

from __future__ import annotations

import threading
import time
from typing import Protocol


class Scheduler(Protocol):
    """What a board's loop needs from time."""

    def now(self) -> float:
        """Seconds on this scheduler's axis (monotonic; the origin is arbitrary)."""
        ...

    def wait_until(self, deadline: float) -> bool:
        """Return once ``now() >= deadline`` (True) or the run is stopping (False)."""
        ...

    def wait(self, seconds: float) -> bool:
        """``wait_until(now() + seconds)``."""
        ...

    @property
    def stopping(self) -> bool:
        """True once the run has been told to stop."""
        ...


SLEEP_SLICE_S = 0.02
"""Real time: the last stretch of a wait is a plain ``time.sleep``, at most this long."""


class RealTimeScheduler:
    """The wall clock. ``stop`` (SIGINT/SIGTERM in a service) ends a wait
    within :data:`SLEEP_SLICE_S`.

    A wait ends on a plain ``time.sleep``: waking from ``Event.wait`` costs
    the re-acquisition of the event's condition lock on top of the sleep
    (measured under SCHED_FIFO at 1 kHz: lateness p50 +10 us, p99 +30 us),
    so a longer wait sleeps on the event up to :data:`SLEEP_SLICE_S` before
    its deadline and then sleeps the rest (docs/timing.md, "Real-time
    measures")."""

    def __init__(self, stop: threading.Event | None = None) -> None:
        self.stop = stop if stop is not None else threading.Event()

    def now(self) -> float:
        return time.monotonic()

    def wait_until(self, deadline: float) -> bool:
        remaining = deadline - time.monotonic()
        if remaining > SLEEP_SLICE_S:
            if self.stop.wait(remaining - SLEEP_SLICE_S):
                return False
            remaining = deadline - time.monotonic()
        if remaining > 0:
            time.sleep(remaining)
        return not self.stop.is_set()

    def wait(self, seconds: float) -> bool:
        return self.wait_until(time.monotonic() + seconds)

    @property
    def stopping(self) -> bool:
        return self.stop.is_set()


class LockstepScheduler(RealTimeScheduler):
    """Wall-clock ``now()`` (for the handshake's timeouts); ``wait_until`` never sleeps."""

    def wait_until(self, deadline: float) -> bool:
        return not self.stop.is_set()


def scheduler_for(clock: str, stop: threading.Event | None = None) -> RealTimeScheduler:
    """The scheduler of a service process in clock mode ``clock`` (realtime or lockstep)."""
    return RealTimeScheduler(stop) if clock == "realtime" else LockstepScheduler(stop)


class SimulatedScheduler:
    """Simulated time that moves only forward and only when asked.

    ``wait_until(t)`` advances the clock to ``t`` (never back), so code
    written against :class:`Scheduler` runs unchanged, in no wall time, under
    a co-simulation master that owns the time axis."""

    def __init__(self, start_s: float = 0.0, stop: threading.Event | None = None) -> None:
        self._now = float(start_s)
        self.stop = stop if stop is not None else threading.Event()

    def now(self) -> float:
        return self._now

    def advance_to(self, t: float) -> None:
        if t > self._now:
            self._now = float(t)

    def wait_until(self, deadline: float) -> bool:
        self.advance_to(deadline)
        return not self.stop.is_set()

    def wait(self, seconds: float) -> bool:
        return self.wait_until(self._now + max(0.0, seconds))

    @property
    def stopping(self) -> bool:
        return self.stop.is_set()
