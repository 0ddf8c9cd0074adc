"""The plant service: RALF's model behind the CANopen analog I/O node, and
its out-of-band test port on zenoh (ground truth, scenario commands,
events) that the controller never uses.

Clock modes (docs/design.md "Time"):

* real time: the model integrates on the wall clock; on every SYNC, RPDO
  or watchdog event it first catches up to ``now`` (in fixed internal
  steps, so the old valve command acted until this instant), then samples
  or applies the command;
* lockstep: the model advances exactly one sample period per SYNC, and the
  SYNC watchdog is off: a pause between SYNCs is the master waiting for its
  handshake (nothing moves in simulated time meanwhile), never a fault, so a
  loaded host cannot trip it and change the run.

Time comes from an injected clock (:mod:`service_kit.clock`); latencies are
measured with an injected stopwatch.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt
import zenoh

from plant_emulator.channel_faults import ChannelFaultUnit
from plant_emulator.node import CanopenNode, NodeConfig
from plant_emulator.params import PlantParams
from plant_emulator.plant_factory import build_plant_model
from plant_emulator.plant_model import PlantModel, ReportsStepFaults, SamplesVolts
from plant_emulator.scenario import PendingCommands
from plant_emulator.xcp_link import PlantXcp, make_plant_xcp
from protocol.can_map import EmcyCode
from protocol.channel_faults import ChannelFault, FaultSchedule
from protocol.errors import ConfigError
from protocol.keys import Keys
from protocol.messages import ChannelTruth, GroundTruth, Health, LatencyStats, PlantEvent, ScenarioCommand, decode, encode
from protocol.param_schedule import parse_param_schedule
from protocol.record_paths import truth_file
from protocol.scenario_setting import parse_channel_faults, parse_scenario, parse_scenario_stimulus
from protocol.settings import PlantSettings
from protocol.stimulus import fault_size_ranges
from protocol.stimulus_eval import StimulusSource
from protocol.stimulus_inputs import channel_fault_target
from service_kit import readiness
from service_kit.clock import Scheduler, scheduler_for
from service_kit.encodings import JSON
from service_kit.inbox import LIMITS, Inbox
from service_kit.param_commands import ParamCommands, write_roles
from service_kit.realtime import RealtimeMeasures, apply_realtime
from service_kit.relink import MovablePort, MovingOut, relinking
from service_kit.runtime import HealthPublisher, LatencyTracker

log = logging.getLogger(__name__)


class DeferredLatency(LatencyTracker):
    """A :class:`~service_kit.runtime.LatencyTracker` for the SYNC path:
    ``add`` only appends to a list (two per SYNC: no lock, no numpy call on
    the tick); the samples enter the tracker's ring, in order, whenever it is
    read (``values``, ``stats``, ``count``) or :data:`FLUSH_AT` have gathered.
    Reading it gives what the plain tracker fed the same samples gives."""

    FLUSH_AT = 1024

    def __init__(self, capacity: int = 65536) -> None:
        super().__init__(capacity)
        self._pending: list[float] = []

    def add(self, seconds: float) -> None:
        pending = self._pending
        pending.append(seconds)
        if len(pending) >= self.FLUSH_AT:
            self._flush()

    def _flush(self) -> None:
        with self._lock:
            pending = self._pending
            n = len(pending)
            if not n:
                return
            batch = pending[:n]
            del pending[:n]  # one list operation: an add from another thread meanwhile stays queued
            values = np.array(batch, dtype=np.float64)
            buf = self._buf
            first = self._n
            if n > buf.size:  # only the newest buf.size samples fit the ring
                first += n - buf.size
                values = values[n - buf.size :]
            buf[(first + np.arange(values.size)) % buf.size] = values
            self._n += n
            self._max = max(self._max, max(batch))

    @property
    def count(self) -> int:
        self._flush()
        return self._n

    def values(self) -> np.ndarray:
        self._flush()
        return super().values()

    def stats(self) -> LatencyStats:
        self._flush()
        return super().stats()


def node_config(settings: PlantSettings) -> NodeConfig:
    """The node's power-on values; lockstep turns the SYNC watchdog off (0x2003 = 0)."""
    periods = 0 if settings.clock == "lockstep" else settings.watchdog_periods
    return NodeConfig(
        node_id=settings.node_id,
        heartbeat_ms=settings.heartbeat_ms,
        sample_period_s=settings.sample_period_s,
        watchdog_periods=periods,
        adc_bits=settings.adc_bits,
    )


SCENARIO_PENDING = 64
"""Scenario commands from the test port that may wait for their time at once."""


class PlantApplication:
    """The node's application: the plant model (``arm``: the RALF arm or an
    FMU, :mod:`plant_emulator.plant_model`), its clock, scenario commands and
    the test port."""

    def __init__(
        self,
        settings: PlantSettings,
        arm: PlantModel | None = None,
        clock: Callable[[], float] = time.monotonic,
        stopwatch: Callable[[], float] = time.perf_counter,
        publish_truth: Callable[[GroundTruth], None] | None = None,
        publish_event: Callable[[PlantEvent], None] | None = None,
        publish_channel_truth: Callable[[ChannelTruth], None] | None = None,
    ) -> None:
        self.settings = settings
        self.arm: PlantModel = arm if arm is not None else build_plant_model(settings)
        self.set_fault: Callable[[int, bool, bytes], None] | None = None
        """Raises/clears a node EMCY (``CanopenNode.set_fault``), wired by whoever builds the node."""
        if isinstance(self.arm, ReportsStepFaults):  # the FMU plant: its step can fail
            self.arm.on_fault = self._model_fault
        self.clock = clock
        self.stopwatch = stopwatch
        self.t0: float | None = None
        self.held = False
        self.sample_period_s = settings.sample_period_s
        self.syncs = 0
        self.scenario_inbox = Inbox("plant", capacity=64, limits=LIMITS)
        """Scenario commands from the test port: rate-limited, bounded, decoded in zenoh's thread (service_kit/inbox.py)."""
        self.publish_truth = publish_truth
        self.publish_event = publish_event
        self.publish_channel_truth = publish_channel_truth
        """The channels' true and faulted values, beside each ground truth while the plant has channel faults."""
        self._truth_seq = 0
        self._channel_truth_seq = 0
        self.sync_service: LatencyTracker = DeferredLatency()
        """Wall time from a SYNC to its sample being ready (model step + A/D)."""
        self.sync_interval: LatencyTracker = DeferredLatency()
        """Wall time between SYNCs as the node saw them."""
        self._last_sync_wall: float | None = None
        self.truth_log: list[GroundTruth] = []
        planned = parse_scenario(settings.scenario)
        self.scenario = PendingCommands(capacity=SCENARIO_PENDING + len(planned))
        """Scenario commands waiting for their time (the setting's and the test port's), bounded."""
        for cmd in planned:
            self.scenario.add(cmd)
        self.channel_faults = self._fault_unit(settings, self.arm)
        """The scenario's channel faults (None: no ``channel_faults`` section, the node's path untouched)."""
        self.stimulus = self._stimulus_source(settings, self.arm, self.channel_faults)
        """The scenario's stimulus on the plant's inputs (None: no ``stimulus`` section, the SYNC path untouched)."""
        self._payload_before: bool | None = None
        self._forces = (0.0, 0.0)
        self._fault_sizes = [(name, target) for name in (self.stimulus.inputs if self.stimulus else ()) if (target := channel_fault_target(name))]
        """The channel faults' sizes the stimulus drives: (input, (fault index, size))."""
        self.channel_faults_refused = 0
        """Channel faults from the test port this plant could not apply."""
        self._live_faults: set[tuple[int, ChannelFault]] = set()
        """The test port's channel-fault commands taken, by (seq, fault)."""
        self._event_seq = 0
        self._next_truth_s = 0.0
        self._hard_stops_seen = 0
        self.lockstep = settings.clock == "lockstep"
        """Each SYNC advances the arm one sample period (else: the wall clock, ``_catch_up``)."""
        self.realtime = settings.clock == "realtime"
        self.wire_arrival_ns: int | None = None
        """The simulated CAN wire's time of the frame being handled (its last bit on the
        plant's sub-step grid, ns since the model's start; docs/can-wire.md "In the simulated
        rig"): the model advances to it before a SYNC's sample or an RPDO1's D/A. None (no
        wire model): one sample period per SYNC, the D/A at once."""
        self._wire_fed_ns = 0
        self._recording_truth = bool(settings.truth_record)
        self._side_channels_due = False
        self.xcp: PlantXcp | None = None
        """The plant's XCP slave (plant_emulator/xcp_link.py), wired by :func:`serve` when a transport is set (off by default)."""
        self.publish_param_change: Callable[[bytes], None] | None = None
        """Sends each change of a plant parameter taken (:class:`~protocol.messages.ParamChanged`, JSON) on ``plant/param_changes``."""
        self.param_changes: list[dict[str, Any]] = []
        """The changes of the plant's parameters taken: ``sim_time_s`` (of the SYNC from which), ``kind``, ``fields``, ``who``."""
        self.params = PlantParams(
            self.arm,
            settings.sample_period_s,
            self._param_taken,
            parse_param_schedule(settings.param_schedule),
            event=self._event,
            counted=settings.param_commands,
            publish=self._publish_param_change,
        )
        """The plant's parameter path (plant_emulator/params.py): XCP writes, ``ralf-hil param``, the schedule."""
        self.param_commands: ParamCommands | None = None
        """``ralf-hil param``'s plant keys (service_kit/param_commands.py), wired by :func:`serve` with ``param_commands``."""

    def _param_taken(self, sim_time_s: float, kind: str, fields: dict[str, float], who: str) -> None:
        self.param_changes.append({"sim_time_s": sim_time_s, "kind": kind, "fields": dict(fields), "who": who})

    def _publish_param_change(self, payload: bytes) -> None:
        if self.publish_param_change is not None:
            self.publish_param_change(payload)

    @staticmethod
    def _fault_unit(settings: PlantSettings, arm: PlantModel) -> ChannelFaultUnit | None:
        """The fault unit of the scenario's ``channel_faults``; refused (one line) for a model whose A/D voltages cannot be read."""
        schedule = parse_channel_faults(settings.scenario)
        if not schedule:
            return None
        unit = ChannelFaultUnit(schedule, keep_record=bool(settings.truth_record))
        if unit.on_inputs and not isinstance(arm, SamplesVolts):
            raise ConfigError(f"channel_faults on the A/D inputs need a model whose input voltages can be read; {type(arm).__name__} has no sample_volts")
        return unit

    @staticmethod
    def _stimulus_source(settings: PlantSettings, arm: PlantModel, unit: ChannelFaultUnit | None) -> StimulusSource | None:
        """The source of the scenario's ``stimulus``; refused (one line) for a model without the inputs it drives.
        A channel fault's size is clipped to the fault's own range (:func:`protocol.stimulus.fault_size_ranges`)."""
        plan = parse_scenario_stimulus(settings.scenario)
        if not plan:
            return None
        ranges = fault_size_ranges(plan, unit.schedule.faults if unit is not None else (), "RALF_SCENARIO stimulus")
        for name in plan.inputs():
            if name in ranges:
                continue
            needs = "set_tip_forces" if name.startswith("disturbance.") else "payload_attached"
            if not hasattr(arm, needs):
                raise ConfigError(f"stimulus on {name}: the plant model {type(arm).__name__} maps no such input (the built-in arm has it)")
        return StimulusSource(plan, ranges)

    def _apply_stimulus(self, source: StimulusSource) -> None:
        """The stimulus at the model's time (docs/stimulus.md): profiles started or ended (plant
        events), the payload while a profile on it is active, the links' tip forces, the channel
        faults' sizes (before this SYNC's conversion, held until the next SYNC)."""
        t = self.arm.time_s
        for change in source.transitions(t):
            self._event("stimulus_start" if change.started else "stimulus_end", change.describe())
        if self._fault_sizes:
            unit = self.channel_faults
            assert unit is not None  # checked at the start (_stimulus_source)
            for name, (index, size) in self._fault_sizes:
                unit.set_size(index, size, source.value(name, t) if source.any_active(name, t) else None)
        if "payload" in source.inputs:
            if source.any_active("payload", t):
                if self._payload_before is None:
                    self._payload_before = bool(self.arm.payload_attached)  # type: ignore[attr-defined]
                self._set_payload(source.value("payload", t) >= 0.5)
            elif self._payload_before is not None:  # the last window ended: back to the payload before it
                self._set_payload(self._payload_before)
                self._payload_before = None
        forces = (source.value("disturbance.link1", t), source.value("disturbance.link2", t))
        if forces != self._forces:
            self._forces = forces
            self.arm.set_tip_forces(*forces)  # type: ignore[attr-defined]  # checked at the start (_stimulus_source)

    def _set_payload(self, attached: bool) -> None:
        if attached != bool(self.arm.payload_attached):  # type: ignore[attr-defined]  # checked at the start
            self.arm.attach_payload(attached)
            self._event("payload", f"payload {'attached' if attached else 'released'} by the stimulus at {self.arm.time_s:.3f} s")

    # -- time ----------------------------------------------------------------------------
    def _catch_up(self) -> None:
        """Real time: integrate the model up to the wall clock."""
        if not self.realtime:
            return
        now = self.clock()
        if self.t0 is None:
            self.t0 = now - self.arm.time_s
        dt = (now - self.t0) - self.arm.time_s
        if dt > 0:
            self.arm.advance(dt)

    # -- NodeApplication ---------------------------------------------------------------------
    def on_sync(self, counter: int) -> tuple[list[int], list[bool]]:
        """Advance to this SYNC (one sample period in lockstep, up to the clock
        in real time), apply the scenario commands due, sample the sensors."""
        if self._side_channels_due:
            self.flush_side_channels()
        arrived = self.stopwatch()
        if self._last_sync_wall is not None:
            self.sync_interval.add(arrived - self._last_sync_wall)
        self._last_sync_wall = arrived
        try:
            xcp = self.xcp
            if self.params.due(self.syncs):  # parameter changes before this SYNC's step (plant_emulator/params.py)
                self.params.before_tick(self.syncs)
            if self.wire_arrival_ns is not None:
                self._advance_to_arrival(self.wire_arrival_ns)
            elif self.lockstep:
                self.arm.advance(self.sample_period_s)
            else:
                self._catch_up()
            self.syncs += 1
            if self.stimulus is not None:
                self._apply_stimulus(self.stimulus)
            if self.scenario or len(self.scenario_inbox):
                self._apply_scenario()
            faults = self.channel_faults
            if faults is None:
                codes, saturated = self.arm.sample_codes()
            else:
                codes, saturated = self._faulted_sample(faults)
            if self.publish_truth is not None or self._recording_truth or self.arm.hard_stop_count != self._hard_stops_seen:
                self._side_channels_due = True  # published once the TPDO is out (flush_side_channels)
            if xcp is not None:
                xcp.after_sync(self.syncs, codes)
            return codes, saturated  # plain ints and bools: the node packs them as they are
        finally:
            self.sync_service.add(self.stopwatch() - arrived)

    def _faulted_sample(self, faults: ChannelFaultUnit) -> tuple[list[int], list[bool]]:
        """The scenario's channel faults inserted or removed by now (plant events), then the A/D sample through them."""
        now = self.arm.time_s
        for change in faults.transitions(now):
            self._event("channel_fault" if change.inserted else "channel_fault_cleared", change.fault.describe())
        if not faults.on_inputs:
            return self.arm.sample_codes()
        arm = self.arm
        assert isinstance(arm, SamplesVolts)
        return faults.convert(now, arm.sample_volts(), arm.adc_scale)

    def flush_side_channels(self) -> None:
        """Publish what the last SYNC left for the test port (ground truth,
        hard-stop events) off the SYNC -> TPDO1 path: the node's runner calls
        it once the TPDO is sent, and every callback calls it before the arm
        moves on, so the truth is the SYNC's state whoever calls first."""
        if self._side_channels_due:
            self._side_channels_due = False
            self._publish_side_channels()

    def _advance_to_arrival(self, t_ns: int) -> None:
        """The simulated wire: the model to ``t_ns`` (never back: a frame on the same sub-step adds nothing)."""
        if t_ns > self._wire_fed_ns:
            self.arm.advance((t_ns - self._wire_fed_ns) / 1e9)
            self._wire_fed_ns = t_ns

    def on_outputs(self, volts: npt.NDArray[np.float64]) -> None:
        if self._side_channels_due:
            self.flush_side_channels()
        if self.realtime:
            self._catch_up()
        elif self.wire_arrival_ns is not None:
            self._advance_to_arrival(self.wire_arrival_ns)
        if not self.held:
            faults = self.channel_faults
            if faults is not None and faults.on_outputs:
                self.arm.set_valve_values(*faults.drive(self.arm.time_s, float(volts[0]), float(volts[1])))
                return
            self.arm.set_valve_voltages(volts if type(volts) is np.ndarray and volts.dtype == np.float64 else np.asarray(volts, dtype=np.float64))

    def on_output_values(self, volts0: float, volts1: float) -> None:
        """:meth:`on_outputs` given the two voltages as floats (the node's RPDO1 path)."""
        if self._side_channels_due:
            self.flush_side_channels()
        if self.realtime:
            self._catch_up()
        elif self.wire_arrival_ns is not None:
            self._advance_to_arrival(self.wire_arrival_ns)
        if not self.held:
            faults = self.channel_faults
            if faults is not None and faults.on_outputs:
                volts0, volts1 = faults.drive(self.arm.time_s, volts0, volts1)
            self.arm.set_valve_values(volts0, volts1)

    def on_watchdog(self, tripped: bool) -> None:
        self.flush_side_channels()
        self._catch_up()
        self.held = tripped
        if tripped:
            faults = self.channel_faults
            if faults is not None and faults.on_outputs:  # the D/A writes zero; a fault behind it still acts
                self.arm.set_valve_values(*faults.drive(self.arm.time_s, 0.0, 0.0))
            else:
                self.arm.set_valve_voltages(np.zeros(2))
            self._event("watchdog", "SYNC lost: valves held at zero")
        else:
            self._event("watchdog_cleared", "SYNC back: valves follow the RPDO again")

    def on_sample_period(self, period_s: float) -> None:
        """The master set object 0x2000: in lockstep, each SYNC advances the
        arm by this much (the watchdog's unit in both modes)."""
        if not 1e-4 <= period_s <= 1.0:
            raise ValueError(f"sample period {period_s} s outside 0.1 ms..1 s")
        self.flush_side_channels()  # the last SYNC's events keep their order
        self.sample_period_s = period_s
        self._event("sample_period", f"sample period set to {period_s * 1e3:.3f} ms by SDO")

    def on_adc_bits(self, bits: int) -> None:
        self.flush_side_channels()
        self.arm.set_adc_bits(bits)
        self._event("adc_bits", f"A/D resolution set to {bits} bits by SDO")

    def _model_fault(self, cause: int, active: bool, detail: str) -> None:
        """The model's step failed (``active``) or is good again: EMCY
        PLANT_MODEL_FAULT (vendor byte 0: the cause) and a plant event."""
        if self.set_fault is not None:
            self.set_fault(EmcyCode.PLANT_MODEL_FAULT, active, bytes([cause & 0xFF]))
        self._event("model_fault" if active else "model_fault_cleared", detail)

    def model_health(self) -> tuple[dict[str, int], dict[str, LatencyStats], str | None]:
        """The model's own counters, step latencies and last problem (none for the RALF arm)."""
        counters = getattr(self.arm, "health_counters", None)
        latencies = getattr(self.arm, "health_latencies", None)
        return (
            counters() if counters is not None else {},
            latencies() if latencies is not None else {},
            getattr(self.arm, "last_problem", None),
        )

    def close(self) -> None:
        """Free the model (an FMU's instance and files); once the node has stopped."""
        self.arm.close()

    # -- scenario and test port ------------------------------------------------------------
    def _apply_scenario(self) -> None:
        if len(self.scenario_inbox):
            for item in self.scenario_inbox.drain():
                self.scenario.add(item.message)
        due = self.scenario.due(self.arm.time_s)
        if not due:
            return
        for cmd in due:
            if cmd.kind == "payload":
                self.arm.attach_payload(bool(cmd.payload_attached))
                self._event("payload", f"payload {'attached' if cmd.payload_attached else 'released'} at {self.arm.time_s:.3f} s")
            elif cmd.kind == "seed":
                self.arm.reseed(int(cmd.seed or 0))
                self._event("seed", f"noise reseeded with {cmd.seed}")
            elif cmd.kind == "adc_bits":
                self.arm.set_adc_bits(int(cmd.adc_bits or 12))
                self._event("adc_bits", f"A/D resolution set to {cmd.adc_bits} bits")
            elif cmd.kind == "channel_fault" and cmd.channel_fault is not None:
                self._add_channel_fault(cmd.seq, cmd.channel_fault)

    def _add_channel_fault(self, seq: int, fault: ChannelFault) -> None:
        """A channel fault from the test port joins the unit (made now if the scenario had none)
        and is told as a plant event (``channel_fault_added``); the same command sent again (same
        ``seq``, same fault: a sender's resend) is taken once. One this plant cannot apply is
        refused, counted and told as an event (``channel_fault_refused``), the node unaffected."""
        if (seq, fault) in self._live_faults:
            return
        self._live_faults.add((seq, fault))
        problem = None
        arm = self.arm
        if fault.is_input and not isinstance(arm, SamplesVolts):
            problem = f"{type(arm).__name__} has no sample_volts"
        elif fault.kind == "lost_bits" and isinstance(arm, SamplesVolts) and fault.bits is not None and fault.bits >= arm.adc_scale.bits:
            problem = f"lost_bits {fault.bits} leaves no bit of the {arm.adc_scale.bits}-bit A/D"
        if problem is not None:
            self.channel_faults_refused += 1
            self._event("channel_fault_refused", f"{fault.describe()}: {problem}")
            return
        if self.channel_faults is None:
            self.channel_faults = ChannelFaultUnit(FaultSchedule(), keep_record=self._recording_truth)
        self.channel_faults.add(fault)
        self._event("channel_fault_added", fault.describe())

    def _event(self, kind: str, detail: str) -> None:
        log.info("plant event %s: %s", kind, detail)
        if self.publish_event is not None:
            self.publish_event(PlantEvent(seq=self._event_seq, sim_time_s=self.arm.time_s, kind=kind, detail=detail))
        self._event_seq += 1

    def _publish_side_channels(self) -> None:
        stops = self.arm.hard_stop_count
        if stops != self._hard_stops_seen:
            self._event("hard_stop", f"{stops - self._hard_stops_seen} joint hard stop(s); total {stops}")
            self._hard_stops_seen = stops
        rate = self.settings.truth_rate_hz
        wanted = self.publish_truth is not None or self.settings.truth_record
        if not wanted or rate <= 0 or self.arm.time_s + 1e-12 < self._next_truth_s:
            return
        self._next_truth_s = self.arm.time_s + 1.0 / rate
        freqs, damping, deflections, theta, tip, payload = self.arm.truth_summary()  # arm.truth()'s fields, only those published
        message = GroundTruth(
            seq=self._truth_seq,
            sim_time_s=self.arm.time_s,
            modal_frequencies_hz=freqs,
            damping_ratios=damping,
            deflections_in=(float(deflections[0]), float(deflections[1])),
            theta_rad=(float(theta[0]), float(theta[1])),
            tip_in=(float(tip[0]), float(tip[1])),
            payload_attached=bool(payload),
            valves_held=self.held,
        )
        if self.publish_truth is not None:
            self.publish_truth(message)
        if self.settings.truth_record:
            self.truth_log.append(message)
        self._truth_seq += 1
        if self.channel_faults is not None and self.publish_channel_truth is not None:
            self.publish_channel_truth(self._channel_truth(self.channel_faults))

    def _channel_truth(self, unit: ChannelFaultUnit) -> ChannelTruth:
        """The last conversion's and D/A update's true and faulted values, and the faults acting now
        (a side the unit does not take, because none of its channels has a fault, is null)."""
        now = self.arm.time_s
        ad = unit.last_conversion if unit.on_inputs else None
        da = unit.last_update
        message = ChannelTruth(
            seq=self._channel_truth_seq,
            sim_time_s=now,
            ai_true_v=tuple(ad[1]) if ad is not None else None,
            ai_faulted_v=tuple(ad[2]) if ad is not None else None,
            ai_saturated=tuple(ad[3]) if ad is not None else None,
            ao_time_s=da[0] if da is not None else None,
            ao_commanded_v=da[1] if da is not None else None,
            ao_applied_v=da[2] if da is not None else None,
            active_faults=tuple(f.describe() for f in unit.acting(now)),
        )
        self._channel_truth_seq += 1
        return message

    def save_truth(self, path: str) -> Path | None:
        """The ground truth recorded during the run, one row per truth sample, in
        ``PATH.truth.npz`` (:func:`protocol.record_paths.truth_file`: never a file
        of the controller's record), written to a temporary name and renamed."""
        log_ = self.truth_log
        if not log_:
            return None
        target = truth_file(path)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = target.with_name(target.name + ".tmp")
        n_modes = min(len(t.modal_frequencies_hz) for t in log_)
        channels = self.channel_faults.record.arrays() if self.channel_faults is not None else {}
        with open(tmp, "wb") as fh:
            self._write_truth(fh, log_, n_modes, channels)
        os.replace(tmp, target)
        return target

    @staticmethod
    def _write_truth(fh: BinaryIO, log_: list[GroundTruth], n_modes: int, channels: dict[str, npt.NDArray[np.generic]]) -> None:
        """The truth rows; with channel faults, also every A/D conversion's and D/A update's true and faulted values (``channel_*``)."""
        arrays: dict[str, Any] = {
            "sim_time_s": np.array([t.sim_time_s for t in log_]),
            "modal_frequencies_hz": np.array([t.modal_frequencies_hz[:n_modes] for t in log_]),
            "damping_ratios": np.array([t.damping_ratios[:n_modes] for t in log_]),
            "deflections_in": np.array([t.deflections_in for t in log_]),
            "theta_rad": np.array([t.theta_rad for t in log_]),
            "tip_in": np.array([t.tip_in for t in log_]),
            "payload_attached": np.array([t.payload_attached for t in log_]),
            "valves_held": np.array([t.valves_held for t in log_]),
            **channels,
        }
        np.savez_compressed(fh, **arrays)


class PlantTestPort(MovablePort):
    """zenoh side of the plant: truth and events out, scenario commands in,
    health. Movable to a new session (:mod:`service_kit.relink`): what the
    node would send while it moves is dropped (the plant is alone then,
    nobody would hear it) and counted (:attr:`moves`, in health); the node's
    thread never waits for the move."""

    def __init__(self, settings: PlantSettings, session: zenoh.Session) -> None:
        self.keys = Keys(settings.rig_id)
        self.inbox = Inbox("plant", capacity=64, limits=LIMITS)
        self.moves = MovingOut()
        """The out lock; moves to a new session and the truth and events sent meanwhile, dropped."""
        self._health_args: tuple[float, Callable[[int], Health]] | None = None
        self._health: HealthPublisher | None = None
        self.bind(session)

    def bind(self, session: zenoh.Session) -> None:
        """Publishers, the scenario subscriber, the liveliness token and (once started) health on ``session``."""
        self.session = session
        self._truth_pub = session.declare_publisher(self.keys.truth, encoding=JSON)
        self._channels_pub = session.declare_publisher(self.keys.channel_truth, encoding=JSON)
        self._event_pub = session.declare_publisher(self.keys.plant_events, encoding=JSON, congestion_control=zenoh.CongestionControl.BLOCK)
        self._param_pub = session.declare_publisher(self.keys.plant_param_changes, encoding=JSON, congestion_control=zenoh.CongestionControl.BLOCK)
        self._sub = session.declare_subscriber(self.keys.scenario, self.inbox.subscriber("scenario", lambda b: decode(ScenarioCommand, b)))
        self._token = session.liveliness().declare_token(self.keys.alive("plant"))
        if self._health_args is not None:
            self._health = HealthPublisher(session, self.keys.health("plant"), *self._health_args).start()
        self.moves.bound_to_new()

    def unbind(self) -> None:
        """Everything :meth:`bind` declared, undeclared (the session may be broken: nothing raises)."""
        self.moves.bound = False
        if self._health is not None:
            self._health.stop()
            self._health = None
        for handle in (self._sub, self._token, self._truth_pub, self._channels_pub, self._event_pub, self._param_pub):
            try:
                handle.undeclare()
            except Exception as exc:  # noqa: BLE001 (a closed session's handles)
                log.debug("undeclare on the old session: %s", exc)

    def start_health(self, period_s: float, build: Callable[[int], Health]) -> None:
        """Health every ``period_s``, on this session and on every one after."""
        self._health_args = (period_s, build)
        self._health = HealthPublisher(self.session, self.keys.health("plant"), period_s, build).start()

    def _put(self, publisher: Callable[[], zenoh.Publisher], payload: bytes) -> None:
        """Sent on the current session; dropped and counted while the port moves (never waits)."""
        self.moves.send(lambda: publisher().put(payload))

    def publish_truth(self, truth: GroundTruth) -> None:
        self._put(lambda: self._truth_pub, encode(truth))

    def publish_event(self, event: PlantEvent) -> None:
        self._put(lambda: self._event_pub, encode(event))

    def publish_channel_truth(self, truth: ChannelTruth) -> None:
        self._put(lambda: self._channels_pub, encode(truth))

    def publish_param_change(self, payload: bytes) -> None:
        """A change of a plant parameter taken (:class:`~protocol.messages.ParamChanged`, JSON)."""
        self._put(lambda: self._param_pub, payload)

    def close(self) -> None:
        with self.moves.lock:
            self.unbind()


def build_health(seq: int, app: PlantApplication, node: CanopenNode, port: PlantTestPort | None, measures: RealtimeMeasures | None = None) -> Health:
    """The plant's health: the node's counters, the SYNC -> sample latency
    (the model's step included) and, for an FMU, its step counters and times."""
    counters = {k: int(v) for k, v in node.counters.as_dict().items()}
    counters.update(syncs_applied=app.syncs, hard_stops=app.arm.hard_stop_count, scenario_pending_dropped=app.scenario.dropped)
    if app.channel_faults_refused:
        counters["channel_faults_refused"] = app.channel_faults_refused
    if port is not None:
        counters.update(port.inbox.as_dict())
        counters.update(port.moves.as_dict())
    counters.update((measures or RealtimeMeasures()).as_counters())
    if app.xcp is not None:
        counters.update(app.xcp.counters())
    counters.update(app.params.counters())  # the parameter path's, when in use (docs/calibration.md)
    if app.param_commands is not None:
        counters.update(app.param_commands.counters())
    model_counters, model_latencies, model_problem = app.model_health()
    counters.update(model_counters)
    latencies = {"sync_to_sample": app.sync_service.stats(), "sync_interval": app.sync_interval.stats(), **model_latencies}
    failed = bool(getattr(app.arm, "fault_active", False))
    return Health(
        seq=seq,
        sim_time_s=app.arm.time_s,
        service="plant",
        state="degraded" if app.held or failed else "running",
        counters=counters,
        latencies=latencies,
        last_miss="valves held: SYNC watchdog" if app.held else model_problem,
    )


def serve(
    settings: PlantSettings,
    session: zenoh.Session,
    bus: object,
    stop: threading.Event,
    scheduler: Scheduler | None = None,
    *,
    owns_process: bool = True,
    model: PlantModel | None = None,
    relink: bool = False,
) -> None:
    """Run the node on ``bus`` until ``stop``; the test port on ``session``.
    ``owns_process``: False when other services share the process (the
    one-process composition): the real-time measures then stay on this thread.
    ``model``: the plant model, already built (default: the one the settings
    name, built here); freed when the node stops. ``relink``: the session is
    the process's own; the port moves to a new one when a session claims
    the plant's zenoh id (:mod:`service_kit.relink`)."""
    from plant_emulator.node import run_node

    model = model if model is not None else build_plant_model(settings)
    try:
        clock = (scheduler or scheduler_for(settings.clock, stop)).now
        port = PlantTestPort(settings, session)
        app = PlantApplication(
            settings,
            arm=model,
            clock=clock,
            publish_truth=port.publish_truth,
            publish_event=port.publish_event,
            publish_channel_truth=port.publish_channel_truth,
        )
        app.scenario_inbox = port.inbox
        bind = getattr(bus, "bind_application", None)
        if callable(bind):  # a simulated wire (workbench.lockstep_wire): the model advances to each arrival
            bind(app)
        node = CanopenNode(app, node_config(settings))
        bind_node = getattr(bus, "bind_node", None)
        if callable(bind_node):  # the simulated wire tells the node its CAN error state (errors injected only)
            bind_node(node)
        app.set_fault = node.set_fault
        app.xcp = make_plant_xcp(settings, model, app.params)
        app.publish_param_change = port.publish_param_change
        if settings.param_commands:
            app.param_commands = ParamCommands(
                session, settings.rig_id, app.params, write_roles(settings.param_write_roles), lambda: app.syncs * settings.sample_period_s
            )
        measures = (
            apply_realtime(settings.realtime.priority, settings.realtime.cpus, whole_process=owns_process, cpu_latency_us=settings.realtime.cpu_latency_us)
            if settings.clock == "realtime"
            else RealtimeMeasures()
        )
        port.start_health(settings.health_period_s, lambda seq: build_health(seq, app, node, port, measures))
    except BaseException:  # the model (an FMU instance) freed on any failure before the node runs
        model.close()
        raise
    if app.xcp is not None:
        app.xcp.start()
    try:
        readiness.mark_ready(settings.ready_file, log)  # kernels warm, node and test port up
        movable: list[Any] = [port] if app.param_commands is None else [port, app.param_commands]
        with relinking(settings, session, movable) if relink else nullcontext() as watch:
            try:
                run_node(bus, node, stop, clock, after_send=app.flush_side_channels)  # type: ignore[arg-type]
            finally:
                if watch is not None:
                    watch.halt()
    finally:
        app.flush_side_channels()
        if settings.truth_record:
            app.save_truth(settings.truth_record)
        port.close()
        if app.param_commands is not None:
            app.param_commands.close()
        if app.xcp is not None:
            app.xcp.close()
        app.close()
        log.info("plant stopped at %.2f s simulated: %s", app.arm.time_s, node.counters.as_dict())
