"""The controller service: the emulated MVME CPU at the edge of CAN and zenoh.

Each tick (thesis §4, docs/design.md "Time"):

1. SYNC -> the plant samples -> TPDO1 (A/D words);
2. flags and interrupts from the DSP are taken in; in lockstep the
   interrupt of the batch in flight is waited for at its due tick (the
   DSP's emulated latency in simulated time), so results do not depend on
   the host's load;
3. set-point -> OATF -> PI -> RPDO1 (D/A);
4. the sample joins the DSP link; a batch goes out when the block is empty;
5. transfer functions are downloaded every ``tf_download_samples``.

Time comes from an injected :class:`service_kit.clock.Scheduler`: real
time paces SYNC at absolute deadlines ``t0 + k Ts`` (no drift); lockstep
(three processes) sends the next SYNC as soon as the tick is done and waits
only for its handshake (SYNC -> TPDO; the interrupt of the batch in flight
at its due tick, whenever it arrives), never for liveliness or the order in
which messages arrive; the co-simulation (:mod:`workbench.cosim`) runs the same
code on simulated time with every answer already in. Before tick 0 the
controller waits until the plant node is operational and the DSP has
answered its reset (the timeouts' ``startup_s``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from controller.can_errors import attach_can_errors
from controller.config import build_trajectory, law_config, run_ticks
from controller.dsp_link import DspLink
from controller.dsp_port import DspPort, ZenohDspPort
from controller.dsp_side import ConfigChangeTaken, DspSide, DspTimes
from controller.fault_stage import FaultStage, LoopStalls
from controller.input_monitors import InputMonitorChecks
from controller.interrupt_wait import BATCH_RESEND_S
from controller.loop import ROW_DEFLECTIONS, ROW_NAMES, ROW_VOLTS, STIMULUS_NAMES, ControlLaw
from controller.monitors import Monitors, MonitorStop
from controller.params import ParamPath
from controller.plant_link import PlantFault, PlantLink, StopRequested
from controller.run_files import make_records, save_run
from controller.schedule import TickSchedule, WakeupMeter
from controller.stale_watch import StaleWatch
from controller.status import STATUS_PERIOD_S, StatusPublisher, build_health
from controller.sync_driver import SyncDriver
from controller.tf_download import TfDownloader
from controller.tick_policy import TickPolicy
from controller.timing_counters import TimingCounters
from controller.xcp_link import XcpLink, make_xcp
from protocol.can_map import NmtCommand
from protocol.messages import TfSnapshot
from protocol.param_schedule import parse_param_schedule
from protocol.settings import ControllerSettings
from service_kit import readiness
from service_kit.clock import Scheduler, scheduler_for
from service_kit.link_faults import Scenario, scenario_setting
from service_kit.param_commands import ParamCommands, write_roles
from service_kit.realtime import RealtimeMeasures, apply_realtime
from service_kit.runtime import LatencyTracker

__all__ = ["RECORD_EXTRA", "ControllerService", "RunResult", "TimingCounters"]

log = logging.getLogger(__name__)

RECORD_EXTRA: tuple[str, ...] = ("oatf_hz", "irq_applied", "stale", "f_id_hz", "f_id2_hz", "zeta_id", "id_confidence")
"""The run record's columns after the law's row (:data:`controller.loop.ROW_NAMES`); ``tick`` is last."""


@dataclass
class RunResult:
    ticks: int
    sim_time_s: float
    counters: dict[str, int]
    error: str | None = None
    liveliness: list[tuple[float, str, bool]] = field(default_factory=list)
    config_changes: list[ConfigChangeTaken] = field(default_factory=list)
    """Every run-time command taken, in order (counted as ``reconfigurations`` in health)."""


def make_port(settings: ControllerSettings, session: zenoh.Session | None, port: DspPort | None) -> DspPort:
    """The given port, or one on the zenoh session."""
    if port is not None:
        return port
    if session is None:
        raise ValueError("a controller needs a zenoh session or a DSP port")
    return ZenohDspPort(session, settings.rig_id)


def make_monitors(settings: ControllerSettings) -> Monitors:
    """The monitors and their policies (docs/design.md, "Monitors")."""
    return Monitors(settings.policies.as_dict())


def make_faults(settings: ControllerSettings, scenario: Scenario | None, lockstep: bool, elapsed: Callable[[], float]) -> FaultStage | None:
    """The scenario's link faults at this controller's edges (controller/fault_stage.py), or None."""
    if scenario is None or not scenario.faults:
        return None
    return FaultStage.from_scenario(scenario, settings.sample_period_s, lockstep, elapsed)


RECORD_COLUMNS: dict[str, type] = {**{name: np.float64 for name in (*ROW_NAMES, *RECORD_EXTRA)}, "tick": np.int64}
"""The run record's columns: the law's row, the service's extras, the tick."""


def record_columns(stimulus: bool) -> dict[str, type]:
    """:data:`RECORD_COLUMNS`; with a controller stimulus, its applied values (:data:`controller.loop.STIMULUS_NAMES`) before the tick."""
    if not stimulus:
        return RECORD_COLUMNS
    names = (*ROW_NAMES, *RECORD_EXTRA, *STIMULUS_NAMES)
    return {**{name: np.float64 for name in names}, "tick": np.int64}


class ControllerService:
    """Runs the loop against the plant (CAN) and the DSP (zenoh)."""

    def __init__(
        self,
        settings: ControllerSettings,
        session: zenoh.Session | None,
        plant: PlantLink,
        law: ControlLaw | None = None,
        *,
        port: DspPort | None = None,
        scheduler: Scheduler | None = None,
        stopwatch: Callable[[], float] = time.perf_counter,
        keep_record: bool = False,
        scenario: Scenario | None = None,
    ) -> None:
        s = self.settings = settings
        self.session, self.plant = session, plant
        self.lockstep = s.clock != "realtime"
        self.clock: Scheduler = scheduler or scheduler_for(s.clock)
        """Schedules the loop and times the handshake."""
        self.stopwatch = stopwatch
        """Measures execution (TET, SYNC lateness): a measurement, never a schedule."""
        self._stopwatch_ns = time.perf_counter_ns if stopwatch is time.perf_counter else lambda: round(stopwatch() * 1e9)
        self.port = make_port(s, session, port)
        self.law = law or ControlLaw(law_config(s), build_trajectory(s))
        self.link = DspLink(sample_rate_hz=s.sample_rate_hz, batch_size=s.batch_size, deadline_s=s.timeouts.dsp_deadline_s)
        self.timing = TimingCounters()
        self.monitors = make_monitors(s)
        self.inputs = InputMonitorChecks(s.input_monitors, self.monitors, s.sample_period_s) if s.input_monitors.any else None
        """The plausibility checks on the A/D inputs, when turned on (controller/input_monitors.py)."""
        self.tet, self.jitter, self.period_jitter = LatencyTracker(), LatencyTracker(), LatencyTracker()
        self.policy: TickPolicy | None = None
        """The per-tick checks of the running loop (controller/tick_policy.py)."""
        self.owns_process = True
        """The service runs in a process of its own (False in the one-process composition):
        under SCHED_FIFO its real-time measures may then move the process's other threads."""
        self._w0 = stopwatch()
        if scenario is None:
            scenario = scenario_setting(s.fault_scenario)
        self.faults = make_faults(s, scenario, self.lockstep, lambda: self.stopwatch() - self._w0)
        attach_can_errors(getattr(plant, "bus", None), scenario)  # the scenario's can_errors on a ralfwire bus (docs/can-errors.md)
        self.injection = LoopStalls.from_scenario(scenario, s.sample_rate_hz)
        """The scenario's loop stalls (controller/fault_stage.py)."""
        self.tick = 0
        self.stale_watch = StaleWatch(self.monitors, self.timing, s.sample_period_s, s.timeouts.stale_after_s, self._note_miss)
        self.ready_at: float | None = None
        """Stopwatch time at which plant and DSP had answered (tick 0 followed)."""
        self.realtime = RealtimeMeasures()
        """Which real-time measures are in effect for the loop (service_kit.realtime)."""
        self._n_ticks: int | None = None
        self._sync_sent_for = -1
        """Lockstep: the tick whose SYNC already went out at the end of the previous tick."""
        self._last_words: tuple[int, ...] = (0, 0, 0, 0)
        self.status = StatusPublisher()
        self.dsp = DspSide(
            self.port,
            self.link,
            self.clock,
            DspTimes(s.sample_period_s, s.timeouts.lockstep_s, s.oatf.min_confidence),
            lockstep=self.lockstep,
            faults=self.faults,
            monitors=self.monitors,
            timing=self.timing,
            law=self.law,
            tick=lambda: self.tick,
        )
        self.hops = self.dsp.hops
        self.sync = SyncDriver(
            plant,
            self.clock,
            self.timing,
            lockstep=self.lockstep,
            faults=self.faults,
            sample_period_s=s.sample_period_s,
            lockstep_timeout_s=s.timeouts.lockstep_s,
        )
        keep_all = bool(s.run_record) or keep_record
        self.tf = TfDownloader(self.port, self.clock, self.timing, self.lockstep, s.tf_download_samples, s.timeouts.lockstep_s, BATCH_RESEND_S, keep_all)
        self.record, self.timing_record = make_records(s.run_record, keep_record, record_columns(self.law.stimulus is not None))
        self.port.connect(self.dsp.inbox.on_port_event, self.clock.now)
        self.params = ParamPath(
            self.law,
            s.sample_period_s,
            self.dsp.config_changes,
            parse_param_schedule(s.param_schedule),
            counted=s.param_commands,
            publish=getattr(self.port, "publish_param_change", None),
            inputs=self.inputs,
        )
        """The one path of run-time parameter changes (controller/params.py)."""
        self.param_commands: ParamCommands | None = None
        """``ralf-hil param``'s keys (service_kit/param_commands.py), with ``param_commands`` on a zenoh session."""
        zsession = session if session is not None else getattr(self.port, "session", None)  # a process of its own: the port's (movable) session
        if s.param_commands and zsession is not None:
            self.param_commands = ParamCommands(zsession, s.rig_id, self.params, write_roles(s.param_write_roles), lambda: self.tick * s.sample_period_s)
        self.xcp: XcpLink | None = make_xcp(self, list(RECORD_COLUMNS))
        """The XCP slave (controller/xcp_link.py), or None (off: the default)."""

    # -- views kept on the service (its health, the tests and the workbench read them) --
    @property
    def overrun_run_max(self) -> int:
        """The longest run of consecutive overrunning ticks."""
        return self.policy.overrun_run_max if self.policy is not None else 0

    @property
    def tf_snapshots(self) -> list[TfSnapshot]:
        """The TF downloads kept (all of them when a record is kept, else the latest)."""
        return self.tf.snapshots

    @property
    def batch_missed(self) -> Any:
        """Per batch answered or lost, in order: 1 if it missed its deadline (:attr:`DspLink.batch_missed`)."""
        return self.link.batch_missed

    @property
    def last_miss(self) -> str | None:
        return self.dsp.last_miss

    @last_miss.setter
    def last_miss(self, text: str | None) -> None:
        self.dsp.last_miss = text

    def _note_miss(self, text: str) -> None:
        self.dsp.last_miss = text

    # -- the tick -----------------------------------------------------------------------
    def _tick(self, words: tuple[int, ...]) -> None:
        tick = self.tick
        if self.params.due(tick):  # parameter changes at the tick boundary (controller/params.py)
            self.params.before_tick(tick)
        dsp = self.dsp
        dsp.drain()
        law, link = self.law, self.link
        sent = link.in_flight
        # apply_interrupts has nothing to do unless a batch's interrupt is due or one is held
        applied = dsp.apply_interrupts() if link.held or (sent is not None and self.lockstep and tick >= sent.due_tick) else False
        faults = self.faults
        w0, w1, w2, w3 = words
        law.tick_compiled(tick, w0, w1, w2, w3)  # the law in one compiled call (controller/fast_tick.py)
        row: list[Any] = law.row.tolist()  # the words as floats: the record stores them as float64 all the same
        if self.inputs is not None:  # before the valves get this tick's command
            self.inputs.check(tick, row)
        volts = row[ROW_VOLTS : ROW_VOLTS + 2]
        if faults is None:
            c0, c1, _, _ = law.codes.tolist()
            self.plant.send_output_codes(c0, c1)
        else:
            for faulted in faults.rpdo(tick, np.array(volts, dtype=np.float64)):
                self.plant.send_outputs(faulted)
        if self.lockstep and (self._n_ticks is None or tick + 1 < self._n_ticks):
            # Lockstep: the next SYNC follows the D/A frame at once (the node takes
            # them in this order, as before), so the plant steps while this tick's
            # bookkeeping runs. Nothing below reaches the plant.
            self.sync.emit(tick + 1)
            self._sync_sent_for = tick + 1
        # add_sample reads both with np.asarray: lists of floats are what it stores
        link.add_sample(tick, volts, row[ROW_DEFLECTIONS : ROW_DEFLECTIONS + 2])  # type: ignore[arg-type]
        tf = self.tf
        if tf.due or (tf.every_samples and tick > 0 and tick % tf.every_samples == 0):  # on_tick does nothing otherwise
            tf.on_tick(tick, link.in_flight is None, dsp.dsp_alive)
        dsp.after_sample(tick)
        self.stale_watch.check(tick, dsp.last_fresh_tick, link.dsp_fft_width)
        degraded = self.monitors.degraded
        if degraded != law.degraded:  # set_degraded of the same state changes nothing
            law.set_degraded(degraded)
        row.extend((law.oatf_frequency_hz, float(applied), float(self.stale_watch.stale), *dsp.interrupt_columns(), *law.stimulus_row, tick))
        self.record.append_row(row)
        if self.xcp is not None:
            self.xcp.after_tick(tick, row)

    # -- the run ------------------------------------------------------------------------
    def run(self, stop: threading.Event) -> RunResult:
        """Start the plant node, wait for the DSP, and run until the duration,
        the trajectory's end, ``stop``, or a plant fault."""
        if hasattr(self.clock, "stop"):
            self.clock.stop = stop
        self.port.start_health(self.settings.health_period_s, lambda seq: build_health(self, seq))
        error: str | None = None
        self._n_ticks = run_ticks(self.settings, self.law.lap_ticks)
        if self.xcp is not None:
            self.xcp.start()
        try:
            self._start(stop)
            self._loop(stop)
        except PlantFault as exc:
            error = str(exc)
            self.timing.plant_faults += 1
            log.error("plant fault: %s; valves to zero", error)
        except StopRequested:
            log.info("stopped before the run began")
        except MonitorStop as exc:
            error = f"stopped by monitor policy: {exc}"
            log.error(error)
        finally:
            self._finish()
        return RunResult(
            ticks=self.tick,
            sim_time_s=self.tick * self.settings.sample_period_s,
            counters={
                **self.link.counters.as_dict(),
                **self.timing.as_dict(),
                **self.plant.counters.as_dict(),
                **self.dsp.inbox.events.as_dict(),
                **(self.faults.as_counters() if self.faults is not None else {}),
                **(self.xcp.counters() if self.xcp is not None else {}),
                **self.params.counters(),
                **(self.param_commands.counters() if self.param_commands is not None else {}),
            },
            error=error,
            liveliness=self.dsp.liveliness,
            config_changes=self.dsp.config_changes,
        )

    def _start(self, stop: threading.Event) -> None:
        """The plant node operational, the DSP's reset answered, real-time measures in place."""
        s = self.settings
        self.plant.start_node(timeout=s.timeouts.startup_s, stop=stop, sample_period_s=s.sample_period_s)
        self.dsp.wait_for_dsp(stop, timeout=s.timeouts.startup_s)
        if not self.lockstep:
            self.realtime = apply_realtime(s.realtime.priority, s.realtime.cpus, whole_process=self.owns_process, cpu_latency_us=s.realtime.cpu_latency_us)
            self.tf.start_worker()  # before tick 0, one FIFO level below the loop
        self.ready_at = self.stopwatch()
        readiness.mark_ready(s.ready_file, log)  # plant node started, DSP seen, kernels warm

    def _finish(self) -> None:
        """Valves to zero, the node pre-operational, the last status out."""
        try:
            self.plant.send_outputs(np.zeros(2))
            self.timing.valves_zeroed += 1
            # A clean end leaves the node pre-operational (valves at zero) rather
            # than tripping its SYNC watchdog.
            self.plant.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
        except Exception:
            log.debug("could not zero the valves", exc_info=True)
        self.status.publish(self, self.stopwatch(), finished=True)

    def _skip_late(self, schedule: TickSchedule) -> bool:
        """Real time, hopelessly behind (a stall, or a rate the host cannot hold):
        those sample instants are gone. Skip them (counted) instead of running
        ticks back to back; the DSP sees the gap and restarts its history.
        True: the run's last tick is skipped too."""
        behind = schedule.periods_behind(self.tick)
        if not behind:
            return False
        self.tick += behind
        self.timing.schedule_resyncs += 1
        self.timing.periods_skipped += behind
        log.warning("loop %d periods late: schedule re-based, samples skipped", behind)
        return self._n_ticks is not None and self.tick >= self._n_ticks

    def _loop(self, stop: threading.Event) -> None:
        """The ticks: SYNC, TPDO1, the tick, its timing, until the run's end or ``stop``."""
        s, lockstep, n_ticks = self.settings, self.lockstep, self._n_ticks
        ts = s.sample_period_s
        # Lockstep: the plant answers every SYNC, so its heartbeat is a liveness
        # check only; a loaded host must not turn a late beat into a fault.
        heartbeat_timeout = max(s.timeouts.plant_heartbeat_s, s.timeouts.lockstep_s) if lockstep else s.timeouts.plant_heartbeat_s
        schedule = TickSchedule(self.clock, ts, realtime=not lockstep)
        schedule.start()
        wakeups = WakeupMeter(ts, self.jitter, self.period_jitter)
        policy = self.policy = TickPolicy(self.monitors, self.plant, ts, heartbeat_timeout, self.timing)
        w0 = self._w0 = self.stopwatch()
        hops, ns, injection, sync, status = self.hops, self._stopwatch_ns, self.injection, self.sync, self.status
        raw, hop_capacity = hops.raw, hops.capacity
        tet, timing_record, rate_window, stopwatch = self.tet, self.timing_record, status.rate_window, self.stopwatch
        while not stop.is_set() and (n_ticks is None or self.tick < n_ticks):
            if injection.stall_at_tick is not None:
                stall = injection.stall_now(self.tick)
                if stall:
                    log.warning("fault injection: the loop stalls for %.2f s", stall)
                    stop.wait(stall)
            if not lockstep and self._skip_late(schedule):
                break
            tick = self.tick
            if not schedule.wait(tick):
                break
            w_start = stopwatch()
            sync_ns = ns()
            if self._sync_sent_for != tick:
                sync.emit(tick)
            wakeup_ns = -1 if lockstep else wakeups.measure(self.clock.now(), schedule.due(tick))
            words = sync.sample(tick)
            tpdo_ns = ns()
            if words is None:
                policy.sample(tick, False)
                words = self._last_words  # hold the last sample for a missed TPDO
            else:
                policy.missed_in_row = 0  # policy.sample(tick, True)
            self._last_words = words
            self._tick(words)
            w_end = stopwatch()
            j = (hops.n % hop_capacity) << 2  # per-hop stamps, inline (controller/hop_timing.py)
            raw[j] = wakeup_ns
            raw[j + 1] = sync_ns
            raw[j + 2] = tpdo_ns
            raw[j + 3] = ns()
            hops.n += 1
            tet_s = w_end - w_start
            tet.add(tet_s)
            timing_record.append_row((tick, w_start - w0, tet_s))
            overran = not lockstep and schedule.overran(tick)
            policy.after_tick(tick, overran, tet_s, hops.blame_tick() if overran else "")
            self.tick = tick + 1
            rate_window.append(w_end)
            policy.check_plant()
            if w_end - status.last >= STATUS_PERIOD_S:  # publish's own test, without the call on every tick
                status.publish(self, w_end)

    # -- files --------------------------------------------------------------------------
    def save(self, path: str, result: RunResult) -> None:
        """Write the run record (deterministic columns), timing and TF downloads."""
        metadata: dict[str, Any] = {"result": result.__dict__, "trajectory": self.law.trajectory.name}
        if self.law.stimulus is not None:
            plan = self.law.stimulus.plan
            metadata["stimulus"] = {"profiles": [p.model_dump(exclude_none=True) for p in plan.profiles], "events": self.law.stimulus_events}
        if self.inputs is not None:
            metadata["input_monitor_events"] = [{"tick": t, "monitor": m, "detail": d} for t, m, d in self.inputs.events]
        hops = self.hops if not self.lockstep else None
        save_run(path, (self.record, self.timing_record), self.settings.model_dump(), metadata, self.faults, hops, self.tf_snapshots)

    def finish(self, result: RunResult) -> None:
        """The end of a run in every clock: its record written when ``run_record`` is set."""
        if self.settings.run_record:
            self.save(self.settings.run_record, result)

    def close(self) -> None:
        self.tf.join(timeout=3.0)
        if self.xcp is not None:
            self.xcp.close()
        if self.param_commands is not None:
            self.param_commands.close()
        self.port.close()
