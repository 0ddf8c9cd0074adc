"""What a service waits for at start-up, said in its log.

A service that waits silently looks hung: a controller without its plant,
or a DSP without its controller, says nothing for a minute. A
:class:`WaitLog` names each thing awaited, in order, in plain words:

    waiting for the plant node 1 on CAN (its boot-up or heartbeat)...
    still waiting for the plant node 1 on CAN (its boot-up or heartbeat): 5 s so far
    plant node 1 heard after 6.2 s

one INFO line when a wait begins, a reminder every :data:`REMIND_EVERY_S`
while it goes on, and one line when it ends. The core (:meth:`WaitLog.step`)
is pure: given the time, it returns the lines to log; :func:`log_waits`
runs it on a thread of its own beside the service, reading the service's
state through the ``arrived`` callables (reads only)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

REMIND_EVERY_S = 5.0
"""Seconds between two reminders of a wait that goes on."""
POLL_S = 0.1
"""How often :func:`log_waits` looks whether the awaited thing arrived."""


@dataclass(frozen=True)
class Awaited:
    """One thing a service waits for."""

    what: str
    """What is awaited, where and how it shows, e.g. ``the DSP on zenoh (its answer to the run-start reset)``."""
    arrived: Callable[[], bool]
    """Whether it has arrived (read from the service's state)."""
    found: str | Callable[[], str]
    """What the end line says, before ``after N s``, e.g. ``DSP ready`` (or a function
    that says it from the service's state when the wait ends)."""


class WaitLog:
    """The lines that say, step by step, what is awaited (pure: time given)."""

    def __init__(self, steps: Sequence[Awaited], started_s: float, remind_s: float = REMIND_EVERY_S) -> None:
        self.steps = list(steps)
        self.remind_s = remind_s
        self.started_s = started_s
        """When the whole wait began: the end lines count from it."""
        self._index = 0
        self._since_s = started_s
        """When the current wait began: reminders count from it."""
        self._next_reminder_s: float | None = None

    @property
    def done(self) -> bool:
        return self._index >= len(self.steps)

    def step(self, now_s: float) -> list[str]:
        """The lines due at ``now_s``: the beginning of a wait (said once, also
        for one that is over at the first look), a reminder when it is overdue,
        its end (time counted from :attr:`started_s`), and so on to the next."""
        lines: list[str] = []
        while not self.done:
            current = self.steps[self._index]
            if self._next_reminder_s is None:
                lines.append(f"waiting for {current.what}...")
                self._next_reminder_s = now_s + self.remind_s
                self._since_s = now_s
            if current.arrived():
                found = current.found if isinstance(current.found, str) else current.found()
                lines.append(f"{found} after {now_s - self.started_s:.1f} s")
                self._index += 1
                self._next_reminder_s = None
                continue
            if now_s >= self._next_reminder_s:
                lines.append(f"still waiting for {current.what}: {now_s - self._since_s:.0f} s so far")
                self._next_reminder_s = now_s + self.remind_s
            break
        return lines


def log_waits(
    steps: Sequence[Awaited],
    log: logging.Logger,
    stop: threading.Event,
    remind_s: float = REMIND_EVERY_S,
    poll_s: float = POLL_S,
    clock: Callable[[], float] = time.monotonic,
) -> threading.Thread:
    """Log ``steps`` as they are awaited (:class:`WaitLog`) from a daemon
    thread, until the last has arrived or ``stop`` is set."""
    waits = WaitLog(steps, clock(), remind_s)

    def watch() -> None:
        while True:
            for line in waits.step(clock()):
                log.info("%s", line)
            if waits.done or stop.wait(poll_s):
                return

    thread = threading.Thread(target=watch, name="start-up-waits", daemon=True)
    thread.start()
    return thread
