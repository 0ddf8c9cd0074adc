"""SYNC out, TPDO1 in: the plant's side of each tick (thesis §4, docs/design.md "Time").

Real time waits for the TPDO1 within ``TPDO_WINDOW`` periods of its SYNC;
lockstep waits for it however long the plant takes, resending a SYNC lost
on the bus. Link faults (controller/fault_stage.py) may drop or delay the
SYNC and the TPDO1 on the way.
"""

from __future__ import annotations

from controller.fault_stage import TPDO_WINDOW, FaultStage
from controller.plant_link import PlantFault, PlantLink
from controller.timing_counters import TimingCounters
from service_kit.clock import Scheduler

LOCKSTEP_RETRY_FRACTION = 0.5
"""Lockstep: resend a SYNC that got no TPDO after this fraction of
``lockstep_timeout_s`` (a frame lost on the bus). Long, so that a merely slow
plant on a starved host is never asked twice (a second SYNC steps it twice)."""


class SyncDriver:
    """Sends each tick's SYNC and takes its TPDO1."""

    def __init__(
        self,
        plant: PlantLink,
        clock: Scheduler,
        timing: TimingCounters,
        *,
        lockstep: bool,
        faults: FaultStage | None,
        sample_period_s: float,
        lockstep_timeout_s: float,
    ) -> None:
        self.plant, self.clock, self.timing = plant, clock, timing
        self.lockstep, self.faults = lockstep, faults
        self._ts = sample_period_s
        self._lockstep_timeout_s = lockstep_timeout_s
        self._late = getattr(plant.bus, "tpdo_late", None)
        """A simulated wire's verdict on the last TPDO1 (workbench.cosim_wire): late after its deadline."""

    def emit(self, tick: int) -> None:
        """The SYNC of ``tick`` (fault injection may drop it on the bus)."""
        if self.faults is not None:
            delay = self.faults.sync(tick)
            if delay is None:  # a link fault lost it: counter advanced, nothing sent, no TPDO to wait for
                self.plant.skip_sync()
                self.timing.syncs_dropped += 1
                return
            if delay > 0:
                self.clock.wait(delay)
        self.plant.send_sync()

    def sample(self, tick: int) -> tuple[int, ...] | None:
        """This tick's four TPDO1 words; None when its SYNC or it was lost."""
        if self.faults is not None:
            return self._faulted_sample(self.faults, tick)
        if not self.lockstep:
            return self.plant.wait_tpdo(TPDO_WINDOW * self._ts)
        words = self._lockstep_sample(tick)
        return None if self._late is not None and self._late() else words

    def _faulted_sample(self, faults: FaultStage, tick: int) -> tuple[int, ...] | None:
        """This tick's TPDO1 through the link faults: None when its SYNC or it was lost."""
        if not faults.expects_tpdo(tick):
            if not self.lockstep:
                self.plant.wait_tpdo(0.0)  # take what is on the bus (stale frames are counted there)
            return None
        words = self._lockstep_sample(tick) if self.lockstep else self.plant.wait_tpdo(TPDO_WINDOW * self._ts)
        if words is None:
            return None
        delay = faults.tpdo(tick)
        if delay is None:
            return None
        if delay > 0:
            self.clock.wait(delay)
        return words

    def _lockstep_sample(self, tick: int) -> tuple[int, ...]:
        """Lockstep: the TPDO for this tick, however long the plant takes. A
        SYNC lost on the bus gets no answer; after ``LOCKSTEP_RETRY_FRACTION``
        of the timeout the SYNC is sent again (the node sees a counter gap and steps once), until
        ``lockstep_timeout_s``."""
        timeout = self._lockstep_timeout_s
        deadline = self.clock.now() + timeout
        # The first wait is the retry interval: (now + timeout) - now >= that fraction of it.
        words = self.plant.wait_tpdo(LOCKSTEP_RETRY_FRACTION * timeout)
        if words is not None:
            return words
        while True:
            if self.clock.now() >= deadline or self.clock.stopping:
                raise PlantFault(f"plant did not answer SYNC at tick {tick} within {timeout:.1f} s")
            self.timing.sync_retries += 1
            self.plant.send_sync()
            retry = min(LOCKSTEP_RETRY_FRACTION * timeout, max(0.0, deadline - self.clock.now()))
            words = self.plant.wait_tpdo(retry)
            if words is not None:
                return words
