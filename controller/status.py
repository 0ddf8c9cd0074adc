"""What the controller reports: its health (counters, latencies, the last
miss; on the health period) and its status (ticks, loop rate, batches;
at most every ``STATUS_PERIOD_S``)."""

from __future__ import annotations

from collections import deque
from typing import Protocol

from controller.dsp_link import DspLink
from controller.dsp_port import DspPort, ZenohDspPort
from controller.dsp_side import DspSide
from controller.fault_stage import FaultStage
from controller.hop_timing import HopTimer
from controller.loop import ControlLaw
from controller.monitors import Monitors
from controller.params import ParamPath
from controller.plant_link import PlantLink
from controller.timing_counters import TimingCounters
from controller.xcp_link import XcpLink
from protocol.messages import ControllerStatus, Health, encode
from protocol.settings import ControllerSettings
from service_kit.param_commands import ParamCommands
from service_kit.realtime import RealtimeMeasures
from service_kit.runtime import LatencyTracker


class ControllerService(Protocol):
    """What the health and the status read of :class:`controller.service.ControllerService`."""

    settings: ControllerSettings
    plant: PlantLink
    link: DspLink
    dsp: DspSide
    port: DspPort
    law: ControlLaw
    monitors: Monitors
    faults: FaultStage | None
    timing: TimingCounters
    realtime: RealtimeMeasures
    tet: LatencyTracker
    jitter: LatencyTracker
    period_jitter: LatencyTracker
    hops: HopTimer
    tick: int
    xcp: XcpLink | None
    params: ParamPath
    param_commands: ParamCommands | None

    @property
    def overrun_run_max(self) -> int: ...


STATUS_PERIOD_S = 0.25
"""The controller's status goes out at most this often (stopwatch seconds)."""
RATE_WINDOW = 200
"""Ticks over which the status's loop rate is measured."""


def build_health(svc: ControllerService, seq: int) -> Health:
    """The controller's health message: every counter, the latencies, the last miss."""
    counters = {
        **svc.plant.counters.as_dict(),
        **svc.link.counters.as_dict(),
        **svc.timing.as_dict(),
        **svc.realtime.as_counters(),
        **svc.dsp.inbox.events.as_dict(),
    }
    if isinstance(svc.port, ZenohDspPort):  # moves to a new zenoh session (service_kit/relink.py)
        counters.update(svc.port.moves.as_dict())
    if svc.faults is not None:
        counters.update(svc.faults.as_counters())
    if svc.xcp is not None:  # the XCP slave's, when it is on (docs/xcp.md)
        counters.update(svc.xcp.counters())
    counters.update(svc.params.counters())  # the parameter path's, when in use (docs/calibration.md)
    if svc.param_commands is not None:
        counters.update(svc.param_commands.counters())
    counters["deadline_miss_run_max"] = svc.link.miss_run_max
    counters["overrun_run_max"] = svc.overrun_run_max
    counters.update({f"episodes_{name}": n for name, n in svc.monitors.episodes.items()})
    if svc.law.supervisor is not None:
        counts = svc.law.supervisor.counts
        counters.update(oatf_out_of_band=counts.out_of_band, oatf_low_confidence=counts.low_confidence, oatf_rejected=counts.design_rejected)
    degraded = svc.monitors.degraded or not svc.dsp.dsp_alive
    return Health(
        seq=seq,
        sim_time_s=svc.tick * svc.settings.sample_period_s,
        service="controller",
        state="degraded" if degraded else "running",
        counters=counters,
        latencies={
            "tet": svc.tet.stats(),
            "sync_jitter": svc.jitter.stats(),
            "sync_period_jitter": svc.period_jitter.stats(),
            "batch_to_interrupt": svc.dsp.irq_latency.stats(),
            **svc.hops.stats(),
        },
        last_miss=svc.monitors.last or svc.dsp.last_miss,
    )


class StatusPublisher:
    """The controller's status, sent at most every ``STATUS_PERIOD_S``."""

    def __init__(self) -> None:
        self.seq = 0
        self.last = 0.0
        """Stopwatch time of the last status sent."""
        self.rate_window: deque[float] = deque(maxlen=RATE_WINDOW)
        """Stopwatch times of the last ticks' ends."""

    def publish(self, svc: ControllerService, now: float, finished: bool = False) -> None:
        if not finished and now - self.last < STATUS_PERIOD_S:
            return
        window = self.rate_window
        rate = 0.0
        if len(window) >= 2:
            span = window[-1] - window[0]
            rate = (len(window) - 1) / span if span > 0 else 0.0
        counters = svc.link.counters
        status = ControllerStatus(
            seq=self.seq,
            sim_time_s=svc.tick * svc.settings.sample_period_s,
            ticks=svc.tick,
            loop_rate_hz=rate,
            batches_sent=counters.batches_sent,
            interrupts=counters.interrupts,
            latest_frequency_hz=svc.dsp.latest_frequency_hz,
            deadline_misses=counters.deadline_misses,
            overruns=svc.timing.overruns,
            finished=finished,
        )
        self.seq += 1
        self.last = now
        svc.port.send_status(encode(status))
