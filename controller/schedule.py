"""The loop's schedule and its wake-up measurement, on an injected
:class:`service_kit.clock.Scheduler` (design.md, "Time").

Real time: tick ``k`` is due at ``t0 + k Ts`` (absolute deadlines, no
drift); a loop more than :data:`RESYNC_AFTER_PERIODS` periods late re-bases
instead of running the lost ticks back to back. Lockstep: the scheduler's
``wait_until`` returns at once (the handshake is the step boundary). The
co-simulation: the simulated clock moves to the tick's time.
"""

from __future__ import annotations

from dataclasses import dataclass

from service_kit.clock import Scheduler
from service_kit.runtime import LatencyTracker

RESYNC_AFTER_PERIODS = 20
"""Real time: a loop this many periods late re-bases its schedule."""


@dataclass
class TickSchedule:
    clock: Scheduler
    sample_period_s: float
    realtime: bool
    t0: float = 0.0

    def start(self) -> None:
        """Tick 0 is due now."""
        self.t0 = self.clock.now()

    def due(self, tick: int) -> float:
        return self.t0 + tick * self.sample_period_s

    def periods_behind(self, tick: int) -> int:
        """Real time: the periods to skip before ``tick`` (0 unless hopelessly late)."""
        if not self.realtime:
            return 0
        late = self.clock.now() - self.due(tick)
        return int(late / self.sample_period_s) if late > RESYNC_AFTER_PERIODS * self.sample_period_s else 0

    def wait(self, tick: int) -> bool:
        """Until tick ``tick`` is due (real time sleeps; lockstep returns; cosim advances). False: stopping."""
        return self.clock.wait_until(self.due(tick))

    def overran(self, tick: int) -> bool:
        """Real time: tick ``tick`` ended after the next one was due."""
        return self.realtime and self.clock.now() > self.due(tick) + self.sample_period_s


@dataclass
class WakeupMeter:
    """Real time: each SYNC's lateness against its deadline and |interval - Ts|."""

    sample_period_s: float
    lateness: LatencyTracker
    period: LatencyTracker
    _last: float | None = None

    def measure(self, start: float, scheduled: float) -> int:
        """One wake-up at ``start`` for ``scheduled``; returns the lateness in ns."""
        late = max(0.0, start - scheduled)
        self.lateness.add(late)
        if self._last is not None:
            self.period.add(abs(start - self._last - self.sample_period_s))
        self._last = start
        return round(late * 1e9)
