"""Whether the OATF's parameters are stale: no fresh confident estimate
from the DSP for ``stale_after_s`` (the ``stale`` monitor, docs/design.md)."""

from __future__ import annotations

from collections.abc import Callable

from controller.monitors import Monitors
from controller.timing_counters import TimingCounters


class StaleWatch:
    """Fires and clears the ``stale`` monitor, counts stale ticks and episodes."""

    def __init__(self, monitors: Monitors, timing: TimingCounters, sample_period_s: float, stale_after_s: float, note_miss: Callable[[str], None]) -> None:
        self.monitors, self.timing = monitors, timing
        self._note_miss = note_miss
        """Records the miss (the service's ``last_miss``) before the monitor fires."""
        self._ts = sample_period_s
        self._stale_after_s = stale_after_s
        self.stale = False

    def check(self, tick: int, fresh: int, history_samples: int) -> None:
        """At ``tick``, the last fresh estimate at tick ``fresh`` (0: none yet).
        Before the first one, the clock starts once the DSP's history can be
        full (``history_samples``, N): no estimate can exist earlier."""
        if fresh == 0:
            fresh = history_samples
            if tick < fresh:
                return
        age = (tick - fresh) * self._ts  # the settings' values, read once (a property per tick cost more than the rest)
        if age > self._stale_after_s:
            if not self.stale:
                self.timing.stale_episodes += 1
                miss = f"parameters stale at tick {tick} ({age:.2f} s without a fresh estimate)"
                self._note_miss(miss)
                self.monitors.fire("stale", miss)
                self.stale = True
            self.timing.stale_ticks += 1
        elif self.stale:
            self.monitors.clear("stale")
            self.stale = False
