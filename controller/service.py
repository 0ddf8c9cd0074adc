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
answered its reset (``startup_timeout_s``).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from array import array
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from controller.config import build_trajectory, law_config, run_ticks
from controller.dsp_link import DspLink
from controller.dsp_port import DspPort, ZenohDspPort
from controller.fault_stage import TPDO_WINDOW, FaultStage, LoopStalls
from controller.hop_timing import HopTimer
from controller.loop import ROW_DEFLECTIONS, ROW_NAMES, ROW_VOLTS, ControlLaw
from controller.monitors import Monitors, MonitorStop
from controller.plant_link import PlantFault, PlantLink, StopRequested
from controller.record import ChunkedRecord, ColumnBuffer, RowCounter
from controller.schedule import TickSchedule, WakeupMeter
from controller.tf_download import TfDownloader
from controller.tick_policy import TickPolicy
from protocol.batch_codec import encode_batch
from protocol.can_map import NmtCommand
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import BlockFlag, ConfigChange, ControllerStatus, Health, Interrupt, TfSnapshot, decode, encode
from protocol.settings import ControllerSettings
from service_kit import readiness
from service_kit.clock import Scheduler, scheduler_for
from service_kit.counters import Counters
from service_kit.inbox import LIMITS, MAX_BYTES, REFUSED, Inbox, Item
from service_kit.link_faults import Scenario, scenario_setting
from service_kit.realtime import RealtimeMeasures, apply_realtime
from service_kit.runtime import LatencyTracker

log = logging.getLogger(__name__)

LOCKSTEP_RETRY_FRACTION = 0.5
"""Lockstep: resend a SYNC that got no TPDO after this fraction of
``lockstep_timeout_s`` (a frame lost on the bus). Long, so that a merely slow
plant on a starved host is never asked twice (a second SYNC steps it twice)."""
BATCH_RESEND_S = 5.0
"""Lockstep: resend the batch in flight when its interrupt has not come this
long after it was due (a message lost when a starved peer's zenoh session
dropped); the DSP answers a repeated batch with the interrupt it raised for
it, or takes it if it never arrived."""
RESET_RESEND_S = 1.0
"""Start-up: resend the run's reset to the DSP this often until it answers."""
STATUS_PERIOD_S = 0.25
"""The controller's status goes out at most this often (stopwatch seconds)."""
RATE_WINDOW = 200
"""Ticks over which the status's loop rate is measured."""
RECORD_EXTRA: tuple[str, ...] = ("oatf_hz", "irq_applied", "stale", "f_id_hz", "f_id2_hz", "zeta_id", "id_confidence")
"""The run record's columns after the law's row (:data:`controller.loop.ROW_NAMES`); ``tick`` is last."""


@dataclass
class TimingCounters(Counters):
    overruns: int = 0
    stale_ticks: int = 0
    stale_episodes: int = 0
    interrupts_applied: int = 0
    oatf_updates: int = 0
    undecodable: int = 0
    tf_downloads: int = 0
    tf_download_failures: int = 0
    dsp_lost: int = 0
    dsp_found: int = 0
    lockstep_waits: int = 0
    syncs_dropped: int = 0
    sync_retries: int = 0
    schedule_resyncs: int = 0
    reconfigurations: int = 0
    periods_skipped: int = 0
    batch_resends: int = 0
    tf_download_retries: int = 0


@dataclass
class RunResult:
    ticks: int
    sim_time_s: float
    counters: dict[str, int]
    error: str | None = None
    liveliness: list[tuple[float, str, bool]] = field(default_factory=list)


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
        self.settings = settings
        self.session = session
        self.plant = plant
        self.lockstep = settings.clock != "realtime"
        self.clock: Scheduler = scheduler or scheduler_for(settings.clock)
        """Schedules the loop and times the handshake."""
        self.stopwatch = stopwatch
        """Measures execution (TET, SYNC lateness): a measurement, never a schedule."""
        if port is None:
            if session is None:
                raise ValueError("a controller needs a zenoh session or a DSP port")
            port = ZenohDspPort(session, settings.rig_id)
        self.port: DspPort = port
        self.keys = Keys(settings.rig_id)
        self.law = law or ControlLaw(law_config(settings), build_trajectory(settings))
        self.link = DspLink(
            sample_rate_hz=settings.sample_rate_hz,
            batch_size=settings.batch_size,
            deadline_s=settings.dsp_deadline_s,
        )
        self.timing = TimingCounters()
        self.monitors = Monitors(settings.policies.as_dict())
        self.tet = LatencyTracker()
        self.jitter = LatencyTracker()
        self.period_jitter = LatencyTracker()
        self.irq_latency = LatencyTracker()
        self.hops = HopTimer()
        """Per-hop stamps of the tick and batch paths (controller/hop_timing.py)."""
        self.batch_missed = array("b")
        """Per batch answered or lost, in order: 1 if it missed its deadline (late or lost), else 0."""
        self._miss_run = 0
        self.miss_run_max = 0
        """The longest run of consecutive batches that missed their deadline."""
        self.policy: TickPolicy | None = None
        self.owns_process = True
        """The service runs in a process of its own (False in the one-process composition):
        under SCHED_FIFO its real-time measures may then move the process's other threads."""
        """The per-tick checks of the running loop (controller/tick_policy.py)."""
        self._stopwatch_ns = time.perf_counter_ns if stopwatch is time.perf_counter else lambda: round(stopwatch() * 1e9)
        if scenario is None:
            scenario = scenario_setting(settings.fault_scenario)
        self.injection = LoopStalls.from_scenario(scenario, settings.sample_rate_hz)
        self._w0 = stopwatch()
        self.faults: FaultStage | None = (
            FaultStage.from_scenario(scenario, settings.sample_period_s, self.lockstep, lambda: self.stopwatch() - self._w0)
            if scenario is not None and scenario.faults
            else None
        )
        """The scenario's link faults at this controller's edges (controller/fault_stage.py), or None."""
        self._ts = settings.sample_period_s
        self._stale_after_s = settings.stale_after_s
        self._lockstep_timeout_s = settings.lockstep_timeout_s
        self.tick = 0
        self.latest_frequency_hz: float | None = None
        self.latest_interrupt: Interrupt | None = None
        self.last_fresh_tick = 0
        self.stale = False
        self.last_miss: str | None = None
        self.dsp_alive = False
        self.ready_at: float | None = None
        self.realtime = RealtimeMeasures()
        self._n_ticks: int | None = None
        self._sync_sent_for = -1
        """Lockstep: the tick whose SYNC already went out at the end of the previous tick."""
        """Which real-time measures are in effect for the loop (service_kit.realtime)."""
        """Stopwatch time at which plant and DSP had answered (tick 0 followed)."""
        self.liveliness: list[tuple[float, str, bool]] = []
        self._last_words: tuple[int, ...] = (0, 0, 0, 0)
        self._config_seq = int.from_bytes(os.urandom(4), "little") >> 2
        """ConfigChange numbers start at random, so a flag of an earlier run never acknowledges this one's reset."""
        self._reset_sent = False
        """The run-start reset went out: the next flag pairs the controller with its board."""
        self._events = Inbox(
            "controller", capacity=256, limits=LIMITS
        )  # decoded at the edge (zenoh's threads), bounded, commands rate-limited (service_kit/inbox.py)
        self._events_waiting = False
        """The port's sink queued something since the loop last drained the inbox."""
        self.paired_board: bytes | None = None
        """The DSP board (session id) this controller takes flags and interrupts from."""
        self._flags_seen = 0
        self._dsp_config_seq: int | None = None
        """The DSP's last applied ConfigChange, from its latest flag."""
        self._last_batch: bytes | None = None
        self._irq_arrival: dict[int, float] = {}
        self._held_interrupts: list[Interrupt] = []
        self._dropped_arrived: set[int] = set()  # batches whose interrupt came and a link fault dropped (lockstep waits for it)
        self._batch_sent_wall: dict[int, float] = {}
        self._batch_sent_unix: dict[int, tuple[float, int]] = {}
        """Per batch in flight: Unix time sent (the batch path's first stamp) and its sample count."""
        self._unix_offset = time.time() - time.monotonic()
        """Unix - monotonic: converts the port's arrival stamps for the batch path's hops (real time)."""
        self._status_seq = 0
        self._dsp_acked = False
        """The DSP flagged its block full since the last batch went out (it has the batch)."""
        self._last_status = 0.0
        self._rate_window: deque[float] = deque(maxlen=RATE_WINDOW)
        names = self._record_names()
        if names != [*ROW_NAMES, *RECORD_EXTRA]:
            raise RuntimeError(f"the record's columns {names} are not the law's row and the service's extras in order")
        columns = {**{name: np.float64 for name in names}, "tick": np.int64}
        self._irq_source: Interrupt | None = None
        self._irq_columns: tuple[float, float, float, float] = (math.nan, math.nan, math.nan, 0.0)
        """f_id_hz, f_id2_hz, zeta_id, id_confidence of ``_irq_source`` (the latest interrupt)."""
        timing_columns = {"tick": np.int64, "sync_wall_s": np.float64, "tet_s": np.float64}
        # RALF_RUN_RECORD set: streamed to disk in chunks. Unset: nothing is kept (flat
        # memory), unless the caller reads the columns (keep_record: in-process runs).
        self._keep_all = bool(settings.run_record) or keep_record
        self.tf = TfDownloader(
            self.port, self.clock, self.timing, self.lockstep, settings.tf_download_samples, settings.lockstep_timeout_s, BATCH_RESEND_S, self._keep_all
        )
        self.record: ChunkedRecord | ColumnBuffer | RowCounter
        self.timing_record: ChunkedRecord | ColumnBuffer | RowCounter
        if settings.run_record:
            self.record = ChunkedRecord(settings.run_record, columns)
            self.timing_record = ChunkedRecord(settings.run_record + ".timing", timing_columns)
        elif keep_record:
            self.record = ColumnBuffer(columns, capacity=4096)
            self.timing_record = ColumnBuffer(timing_columns, capacity=4096)
        else:
            self.record = RowCounter(columns)
            self.timing_record = RowCounter(timing_columns)
        self._decoders: dict[str, Callable[..., Any]] = {
            "flag": self._decode_flag,
            "interrupt": self._decode_interrupt,
            "command": lambda b: decode(ConfigChange, b),
        }
        self.port.connect(self._on_port_event, self.clock.now)

    def _note_batch(self, missed: bool) -> None:
        """A batch was answered (``missed``: past its deadline) or lost (missed)."""
        self.batch_missed.append(1 if missed else 0)
        self._miss_run = self._miss_run + 1 if missed else 0
        self.miss_run_max = max(self.miss_run_max, self._miss_run)

    @property
    def overrun_run_max(self) -> int:
        """The longest run of consecutive overrunning ticks."""
        return self.policy.overrun_run_max if self.policy is not None else 0

    @property
    def tf_snapshots(self) -> list[TfSnapshot]:
        """The TF downloads kept (all of them when a record is kept, else the latest)."""
        return self.tf.snapshots

    # -- bookkeeping --------------------------------------------------------------------
    def _record_names(self) -> list[str]:
        probe = self.law.record_row(0, self.law.step(0, np.zeros(4)))
        self.law.pi.reset()
        if self.law.oatf is not None:
            self.law.oatf.reset(self.law.setpoint(0) if self.settings.oatf.location == "outer" else 0.0)
        return [k for k in probe if k != "tick"] + ["irq_applied", "stale", "f_id_hz", "f_id2_hz", "zeta_id", "id_confidence"]

    def _on_port_event(self, kind: str, payload: Any, arrival: float, attachment: Any = None) -> None:
        """The port's sink, called in its thread (zenoh's, for the zenoh port):
        size-capped, decoded and checked here, then queued (service_kit/inbox.py)."""
        if kind == "alive":
            self._events.put("alive", payload == b"1", arrival)
            self._events_waiting = True
            return
        decoder = self._decoders.get(kind)
        if decoder is None:
            return
        if kind in ("flag", "interrupt"):
            self._events.offer(kind, payload, decoder, MAX_BYTES[kind], attachment=attachment, use_attachment=True, arrival=arrival)
        else:
            self._events.offer(kind, payload, decoder, MAX_BYTES[kind], arrival=arrival)
        self._events_waiting = True  # after the item: the loop clears this before it drains

    def _decode_flag(self, payload: bytes, board: bytes | None) -> BlockFlag | object | None:
        """At the edge: the first flag after the run-start reset pairs the
        controller with its board (the DSP session's id, sent as the
        attachment); flags of any other board are refused."""
        flag = decode(BlockFlag, payload)
        if not self._reset_sent:
            return None  # the board announcing itself before the run-start reset: expected, nothing to pair with yet (counted as handled)
        if self.paired_board is None and board:
            self.paired_board = board
            log.info("paired with DSP board %s", board.decode(errors="replace"))
        return flag if board is not None and board == self.paired_board else REFUSED

    def _decode_interrupt(self, payload: bytes, board: bytes | None) -> Interrupt | object:
        """At the edge: an interrupt from another board than the paired one,
        or for no batch we sent, is refused before it can take a place in the
        inbox (a flood must not crowd out the real one)."""
        irq = decode(Interrupt, payload)
        if board is None or board != self.paired_board:
            return REFUSED
        return irq if irq.batch_seq in self._batch_sent_wall else REFUSED

    def _build_health(self, seq: int) -> Health:
        counters = {
            **self.plant.counters.as_dict(),
            **self.link.counters.as_dict(),
            **self.timing.as_dict(),
            **self.realtime.as_counters(),
            **self._events.as_dict(),
        }
        if self.faults is not None:
            counters.update(self.faults.as_counters())
        counters["deadline_miss_run_max"] = self.miss_run_max
        counters["overrun_run_max"] = self.overrun_run_max
        counters.update({f"episodes_{name}": n for name, n in self.monitors.episodes.items()})
        if self.law.supervisor is not None:
            counts = self.law.supervisor.counts
            counters.update(oatf_out_of_band=counts.out_of_band, oatf_low_confidence=counts.low_confidence, oatf_rejected=counts.design_rejected)
        degraded = self.monitors.degraded or not self.dsp_alive
        return Health(
            seq=seq,
            sim_time_s=self.tick * self.settings.sample_period_s,
            service="controller",
            state="degraded" if degraded else "running",
            counters=counters,
            latencies={
                "tet": self.tet.stats(),
                "sync_jitter": self.jitter.stats(),
                "sync_period_jitter": self.period_jitter.stats(),
                "batch_to_interrupt": self.irq_latency.stats(),
                **self.hops.stats(),
            },
            last_miss=self.monitors.last or self.last_miss,
        )

    def _publish_status(self, finished: bool = False, now: float | None = None) -> None:
        if now is None:
            now = self.stopwatch()
        if not finished and now - self._last_status < STATUS_PERIOD_S:
            return
        rate = 0.0
        if len(self._rate_window) >= 2:
            span = self._rate_window[-1] - self._rate_window[0]
            rate = (len(self._rate_window) - 1) / span if span > 0 else 0.0
        status = ControllerStatus(
            seq=self._status_seq,
            sim_time_s=self.tick * self.settings.sample_period_s,
            ticks=self.tick,
            loop_rate_hz=rate,
            batches_sent=self.link.counters.batches_sent,
            interrupts=self.link.counters.interrupts,
            latest_frequency_hz=self.latest_frequency_hz,
            deadline_misses=self.link.counters.deadline_misses,
            overruns=self.timing.overruns,
            finished=finished,
        )
        self._status_seq += 1
        self._last_status = now
        self.port.send_status(encode(status))

    # -- DSP side -----------------------------------------------------------------------
    def _take_event(self, kind: str, payload: Any, arrival: float) -> None:
        """One decoded message from the inbox (never raw bytes: decoding
        happened in zenoh's thread)."""
        try:
            if kind == "flag":
                flag = payload
                if flag.state == "full":
                    self._dsp_acked = True
                if not self._echoes_interrupt(flag):
                    self.link.on_flag(flag)
                self._flags_seen += 1
                self._dsp_config_seq = flag.config_seq
            elif kind == "interrupt":
                irq = payload
                self._irq_arrival[irq.batch_seq] = arrival
                while len(self._irq_arrival) > 64:  # unmatched ones (lost or foreign) must not accumulate
                    del self._irq_arrival[next(iter(self._irq_arrival))]
                if self.faults is None:
                    self._held_interrupts.append(irq)
                else:
                    taken = self.faults.interrupt(irq, irq.batch_seq)
                    if not taken and self.faults.lost(irq.batch_seq):
                        self.link.on_released(irq)  # dropped: its block-empty part still holds (no flag follows it)
                        if self.lockstep:  # its due tick waits for it (real time never does)
                            self._dropped_arrived.add(irq.batch_seq)
                            if len(self._dropped_arrived) > 64:  # one that came after its wait timed out
                                self._dropped_arrived.discard(min(self._dropped_arrived))
                    self._held_interrupts.extend(taken)  # type: ignore[arg-type]
            elif kind == "command":
                self.reconfigure(payload)
            elif kind == "alive":
                up = bool(payload)
                if up != self.dsp_alive and not up:
                    self.paired_board = None  # a restarted board pairs anew with its first flag
                if up != self.dsp_alive and self.lockstep:
                    # Lockstep: presence is reported, never acted on; the handshake
                    # (an interrupt within lockstep_timeout_s) decides.
                    self.liveliness.append((self.tick * self.settings.sample_period_s, "dsp", up))
                    if up:
                        self.timing.dsp_found += 1
                    else:
                        self.timing.dsp_lost += 1
                elif up != self.dsp_alive:
                    self.liveliness.append((self.tick * self.settings.sample_period_s, "dsp", up))
                    if up:
                        self.timing.dsp_found += 1
                        self.monitors.clear("dsp_lost")
                        log.info("DSP present at tick %d", self.tick)
                    else:
                        self.timing.dsp_lost += 1
                        self.last_miss = f"DSP lost at tick {self.tick}"
                        self.link.in_flight = None
                        self.link.block_empty = False
                        self.monitors.fire("dsp_lost", f"DSP lost at tick {self.tick}; controlling on with the fallback parameters")
                self.dsp_alive = up
        except ProtocolError as exc:
            self.timing.undecodable += 1
            log.warning("dropped an invalid %s: %s", kind, exc)

    def _echoes_interrupt(self, flag: BlockFlag) -> bool:
        """The empty flag the DSP sends just after an interrupt (it raises the
        interrupt first, docs/design.md): that interrupt already emptied the
        block and our next batch may be in flight, so the flag is no news for
        the link (not a late flag)."""
        irq, sent = self.latest_interrupt, self.link.in_flight
        return flag.state == "empty" and irq is not None and sent is not None and flag.next_batch_seq == irq.batch_seq + 1 == sent.seq

    def reconfigure(self, change: ConfigChange) -> None:
        """A run-time command (thesis §3.2.3): the batch size applies here
        from the next batch on; the FFT width, alpha and latency go to the
        DSP, which zeroes its history on an FFT-width change."""
        if change.batch_size is not None:
            log.info("batch size %d -> %d", self.link.batch_size, change.batch_size)
            self.link.batch_size = change.batch_size
        self._config_seq += 1
        forwarded = change.model_copy(update={"seq": self._config_seq, "sim_time_s": self.tick * self.settings.sample_period_s})
        self.port.send_config(encode(forwarded))
        self.timing.reconfigurations += 1

    def _drain_events(self) -> None:
        # Nothing queued on almost every tick: the flag (set by the port's sink after
        # each item, cleared here before draining) spares asking the queue's lock.
        if self._events_waiting:
            self._events_waiting = False
            if len(self._events):
                for kind, message, arrival in self._events.drain(limit=self._events.capacity):
                    self._take_event(kind, message, arrival)
                if len(self._events):
                    self._events_waiting = True  # more than one drain's limit: the next tick takes the rest
        if self.faults is not None and not self.lockstep:
            self._held_interrupts.extend(self.faults.interrupts_due())  # type: ignore[arg-type]
            for payload in self.faults.batches_due():
                self.port.send_batch(payload)

    def _next_event(self, timeout: float) -> Item | None:
        """The next DSP-side event (decoded), waiting up to ``timeout`` wall
        seconds (not at all when the port answers synchronously)."""
        if self.port.synchronous:
            return self._events.get_nowait()
        return self._events.get(timeout=timeout)

    def _wait_for_interrupt(self, seq: int) -> None:
        """Lockstep: block until the interrupt of batch ``seq`` is in, however
        long it takes to arrive (the DSP's presence is not asked), up to
        ``lockstep_timeout_s``: then it is declared lost."""
        if self.faults is not None and self.faults.lost(seq):
            came = True
            if not self._dsp_never_got(seq):
                # Only the interrupt was dropped: it still releases the DSP's block, and the
                # next batch waits for that, so the handshake waits for it to come (and be
                # dropped) here, not whenever the DSP's thread gets to it.
                came = self._await_interrupt(seq, lambda: seq in self._dropped_arrived)
                self._dropped_arrived.discard(seq)
            self._fault_lost(seq, answered=came)
            return
        if not self._await_interrupt(seq, lambda: any(irq.batch_seq == seq for irq in self._held_interrupts)):
            # It will not come: count it lost, fire the deadline monitor, go on without it.
            self.link.declare_lost()
            self._note_batch(True)
            self.last_miss = f"batch {seq}: no interrupt within {self.settings.lockstep_timeout_s:.1f} s (lockstep); declared lost"
            self.monitors.fire("deadline", self.last_miss)

    def _await_interrupt(self, seq: int, arrived: Callable[[], bool]) -> bool:
        """Take DSP-side events until ``arrived()`` (the interrupt of batch ``seq``
        is in), resending the batch every ``BATCH_RESEND_S``; False after
        ``lockstep_timeout_s``, at a stop, or at once when the port answers
        synchronously and it is not in."""
        deadline = self.clock.now() + self.settings.lockstep_timeout_s
        resend_at = self.clock.now() + BATCH_RESEND_S
        self.timing.lockstep_waits += 1
        while not arrived():
            if not self.port.synchronous and self._last_batch is not None and self.clock.now() >= resend_at:
                self.port.send_batch(self._last_batch)
                self.timing.batch_resends += 1
                resend_at = self.clock.now() + BATCH_RESEND_S
            remaining = deadline - self.clock.now()
            event = self._next_event(min(remaining, 0.1)) if remaining > 0 and not self.clock.stopping else None
            if event is None and (remaining <= 0 or self.port.synchronous or self.clock.stopping):
                return False
            if event is not None:
                self._take_event(*event)
        return True

    def _fault_lost(self, seq: int, answered: bool = True) -> None:
        """Lockstep: batch ``seq`` or its interrupt was dropped by a link fault,
        so it is lost at its due tick (once a dropped interrupt has come:
        ``answered`` False if the board did not answer within
        ``lockstep_timeout_s`` either, which the miss says). A batch that never
        reached the DSP leaves its block empty and expecting ``seq`` (the flag
        the CPU reads, Fig. 3.5): the next batch takes that number again and
        says its samples are missing, so the DSP restarts its history."""
        assert self.faults is not None
        self.link.declare_lost()
        self._note_batch(True)
        sent = self._batch_sent_unix.pop(seq, None)
        if self.faults.engine.covers("batch") and self._dsp_never_got(seq):
            self.link.next_seq = seq
            self.link.block_empty = True
            self.link.note_lost_samples(sent[1] if sent is not None else 0)
        self.last_miss = f"batch {seq}: interrupt lost at its due tick {self.tick} ({self.faults.blame(seq)})"
        if not answered:
            self.last_miss += f"; the board did not answer within {self.settings.lockstep_timeout_s:.1f} s either"
        self.monitors.fire("deadline", self.last_miss)

    def _dsp_never_got(self, seq: int) -> bool:
        assert self.faults is not None
        return seq in self.faults.batches_dropped

    def _apply_interrupts(self) -> bool:
        """Apply held interrupts that are due; True if one was applied this tick.
        Lockstep: the interrupt of the batch in flight is applied exactly at
        its due tick (waited for there), never earlier or later."""
        lockstep = self.lockstep
        sent = self.link.in_flight
        if lockstep and sent is not None and self.tick >= sent.due_tick:
            self._wait_for_interrupt(sent.seq)
        if not self._held_interrupts:
            return False
        applied = False
        keep: list[Interrupt] = []
        for irq in self._held_interrupts:
            sent = self.link.in_flight
            if lockstep and sent is not None and irq.batch_seq == sent.seq and self.tick < sent.due_tick:
                keep.append(irq)  # not due yet in simulated time
                continue
            matched = self.link.on_interrupt(irq)
            if matched is None:
                continue
            sent_wall = self._batch_sent_wall.pop(irq.batch_seq, None)
            arrived = self._irq_arrival.pop(irq.batch_seq, self.clock.now())
            if sent_wall is not None:
                self.irq_latency.add(arrived - sent_wall)
            sent_unix = self._batch_sent_unix.pop(irq.batch_seq, None)
            if sent_unix is not None and not self.port.synchronous:
                now_unix = time.time()
                hold = 0.0 if self.lockstep else max(0.0, self.link.dsp_latency_s - irq.compute_time_s)
                self.hops.batch(sent_unix[0], irq.wall_time_s, irq.compute_time_s, hold, arrived + self._unix_offset, now_unix)
            self.timing.interrupts_applied += 1
            self._note_batch(self.link.missed_current)
            applied = True
            if not self.link.missed_current:
                self.monitors.clear("deadline")
            self.latest_interrupt = irq
            if irq.poles:
                self.latest_frequency_hz = irq.poles[0].frequency_hz
            if irq.poles and irq.confidence >= self.settings.oatf.min_confidence:
                self.last_fresh_tick = self.tick
            if self.law.apply_interrupt(irq):
                self.timing.oatf_updates += 1
        self._held_interrupts = keep
        return applied

    def _maybe_send_batch(self) -> None:
        taken = self.link.take_batch(self.tick, self.tick * self.settings.sample_period_s)
        if taken is None:
            return
        sent, batch = taken
        sent_unix = time.time()
        if not self.port.synchronous:
            batch = type(batch)(**{**batch.__dict__, "wall_time_s": sent_unix})
        self._batch_sent_wall[sent.seq] = self.clock.now()
        self._batch_sent_unix[sent.seq] = (sent_unix, batch.n_samples)
        while len(self._batch_sent_wall) > 64:  # batches never answered must not accumulate
            del self._batch_sent_wall[next(iter(self._batch_sent_wall))]
        while len(self._batch_sent_unix) > 64:
            del self._batch_sent_unix[next(iter(self._batch_sent_unix))]
        payload = encode_batch(batch)
        self._last_batch = payload
        self._dsp_acked = False
        if self.faults is not None:
            self._dropped_arrived.discard(sent.seq)  # a number taken again (a lost batch, a DSP restart) starts clean
            send, shift = self.faults.batch(sent.seq, self.tick, payload)
            if shift and self.link.in_flight is sent:
                self.link.in_flight = dataclasses.replace(sent, due_tick=sent.due_tick + shift)
            if not send:
                if self.faults.lost(sent.seq):
                    self._last_batch = None  # lost on the wire: never resent
                return
        self.port.send_batch(payload)

    def _blame_batch(self) -> str:
        """Which hop of the batch in flight ate its deadline: a link fault, the
        DSP (it acknowledged the batch: block full) or the way there (no
        acknowledgement yet)."""
        sent = self.link.in_flight
        if sent is not None and self.faults is not None:
            fault = self.faults.blame(sent.seq)
            if fault:
                return fault
        if sent is not None and sent.due_tick > sent.deadline_tick:
            return f"the DSP's emulated latency ({(sent.due_tick - sent.tick) * self.settings.sample_period_s * 1e3:.0f} ms) exceeds the deadline"
        if not self.link.block_empty and self._dsp_acked:
            return "hop dsp_compute: the DSP acknowledged the batch and has not answered"
        return "hop batch_to_dsp: no acknowledgement from the DSP yet"

    def _check_stale(self) -> None:
        """Stale: no fresh confident estimate for ``stale_after_s``. Before the
        first one, the clock starts once the DSP's history can be full (N
        samples): no estimate can exist earlier."""
        tick, fresh = self.tick, self.last_fresh_tick
        if fresh == 0:
            fresh = self.link.dsp_fft_width
            if tick < fresh:
                return
        age = (tick - fresh) * self._ts  # the settings' values, read once (a property per tick cost more than the rest)
        stale = age > self._stale_after_s
        was = self.stale
        if stale:
            if not was:
                self.timing.stale_episodes += 1
                self.last_miss = f"parameters stale at tick {tick} ({age:.2f} s without a fresh estimate)"
                self.monitors.fire("stale", self.last_miss)
                self.stale = True
            self.timing.stale_ticks += 1
        elif was:
            self.monitors.clear("stale")
            self.stale = False

    # -- the loop -----------------------------------------------------------------------
    def _tick(self, words: tuple[int, ...]) -> None:
        self._drain_events()
        tick = self.tick
        law, link = self.law, self.link
        sent = link.in_flight
        # _apply_interrupts has nothing to do unless a batch's interrupt is due or one is held
        applied = self._apply_interrupts() if self._held_interrupts or (sent is not None and self.lockstep and tick >= sent.due_tick) else False
        faults = self.faults
        if law.compiled:  # the law in one compiled call (controller/fast_tick.py): the same values
            w0, w1, w2, w3 = words
            law.tick_compiled(tick, w0, w1, w2, w3)
            row: list[Any] = law.row.tolist()  # the words as floats: the record stores them as float64 all the same
            if faults is None:
                c0, c1, _, _ = law.codes.tolist()
                self.plant.send_output_codes(c0, c1)
        else:
            row = law.step_row(tick, list(words))
            if faults is None:
                self.plant.send_output_values(row[ROW_VOLTS : ROW_VOLTS + 2])
        volts = row[ROW_VOLTS : ROW_VOLTS + 2]
        if faults is not None:
            for faulted in faults.rpdo(tick, np.array(volts, dtype=np.float64)):
                self.plant.send_outputs(faulted)
        if self.lockstep and (self._n_ticks is None or tick + 1 < self._n_ticks):
            # Lockstep: the next SYNC follows the D/A frame at once (the node takes
            # them in this order, as before), so the plant steps while this tick's
            # bookkeeping runs. Nothing below reaches the plant.
            self._emit_sync(tick + 1)
            self._sync_sent_for = tick + 1
        # add_sample reads both with np.asarray: lists of floats are what it stores
        link.add_sample(tick, volts, row[ROW_DEFLECTIONS : ROW_DEFLECTIONS + 2])  # type: ignore[arg-type]
        tf = self.tf
        if tf.due or (tf.every_samples and tick > 0 and tick % tf.every_samples == 0):  # on_tick does nothing otherwise
            tf.on_tick(tick, link.in_flight is None, self.dsp_alive)
        if link.ready():
            self._maybe_send_batch()
        if link.in_flight is not None and link.check_deadline(tick):
            self.last_miss = f"batch {link.in_flight.seq if link.in_flight else '?'}: no interrupt within {link.deadline * 1e3:.0f} ms ({self._blame_batch()})"
            self.monitors.fire("deadline", self.last_miss)
        self._check_stale()
        degraded = self.monitors.degraded
        if degraded != law.degraded:  # set_degraded of the same state changes nothing
            law.set_degraded(degraded)
        irq = self.latest_interrupt
        if irq is not self._irq_source:
            self._irq_source = irq
            poles = irq.poles if irq is not None else ()
            self._irq_columns = (
                poles[0].frequency_hz if poles else math.nan,
                poles[1].frequency_hz if len(poles) > 1 else math.nan,
                poles[0].damping_ratio if poles else math.nan,
                irq.confidence if irq is not None else 0.0,
            )
        row.extend((law.oatf_frequency_hz, float(applied), float(self.stale), *self._irq_columns, tick))
        self.record.append_row(row)

    def run(self, stop: threading.Event) -> RunResult:
        """Start the plant node, wait for the DSP, and run until the duration,
        the trajectory's end, ``stop``, or a plant fault."""
        s = self.settings
        if hasattr(self.clock, "stop"):
            self.clock.stop = stop
        self.port.start_health(s.health_period_s, self._build_health)
        error: str | None = None
        n_ticks = run_ticks(s, self.law.lap_ticks)
        self._n_ticks = n_ticks
        ts = s.sample_period_s
        lockstep = self.lockstep
        # Lockstep: the plant answers every SYNC, so its heartbeat is a liveness
        # check only; a loaded host must not turn a late beat into a fault.
        heartbeat_timeout = max(s.plant_heartbeat_timeout_s, s.lockstep_timeout_s) if lockstep else s.plant_heartbeat_timeout_s
        try:
            self.plant.start_node(timeout=s.startup_timeout_s, stop=stop, sample_period_s=ts)
            self._wait_for_dsp(stop, timeout=s.startup_timeout_s)
            if not lockstep:
                self.realtime = apply_realtime(s.realtime.priority, s.realtime.cpus, whole_process=self.owns_process, cpu_latency_us=s.realtime.cpu_latency_us)
                self.tf.start_worker()  # before tick 0, one FIFO level below the loop
            self.ready_at = self.stopwatch()
            readiness.mark_ready(s.ready_file, log)  # plant node started, DSP seen, kernels warm
            schedule = TickSchedule(self.clock, ts, realtime=not lockstep)
            schedule.start()
            wakeups = WakeupMeter(ts, self.jitter, self.period_jitter)
            policy = self.policy = TickPolicy(self.monitors, self.plant, ts, heartbeat_timeout, self.timing)
            w0 = self._w0 = self.stopwatch()
            faults = self.faults
            hops = self.hops
            raw, hop_capacity = hops.raw, hops.capacity
            ns = self._stopwatch_ns
            injection = self.injection
            tet, timing_record, rate_window = self.tet, self.timing_record, self._rate_window
            stopwatch, plant = self.stopwatch, self.plant
            while not stop.is_set() and (n_ticks is None or self.tick < n_ticks):
                if injection.stall_at_tick is not None:
                    stall = injection.stall_now(self.tick)
                    if stall:
                        log.warning("fault injection: the loop stalls for %.2f s", stall)
                        stop.wait(stall)
                if not lockstep:
                    behind = schedule.periods_behind(self.tick)
                    if behind:
                        # Hopelessly behind (a stall, or a rate the host cannot hold): those
                        # sample instants are gone. Skip them (counted) instead of running
                        # ticks back to back; the DSP sees the gap and restarts its history.
                        self.tick += behind
                        self.timing.schedule_resyncs += 1
                        self.timing.periods_skipped += behind
                        log.warning("loop %d periods late: schedule re-based, samples skipped", behind)
                        if n_ticks is not None and self.tick >= n_ticks:
                            break
                tick = self.tick
                if not schedule.wait(tick):
                    break
                w_start = stopwatch()
                sync_ns = ns()
                if self._sync_sent_for != tick:
                    self._emit_sync(tick)
                wakeup_ns = -1 if lockstep else wakeups.measure(self.clock.now(), schedule.due(tick))
                if faults is None:
                    words = self._lockstep_sample() if lockstep else plant.wait_tpdo(TPDO_WINDOW * ts)
                else:
                    words = self._faulted_sample(faults, ts)
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
                if w_end - self._last_status >= STATUS_PERIOD_S:  # _publish_status's own test, without the call on every tick
                    self._publish_status(now=w_end)
        except PlantFault as exc:
            error = str(exc)
            log.error("plant fault: %s; valves to zero", error)
        except StopRequested:
            log.info("stopped before the run began")
        except MonitorStop as exc:
            error = f"stopped by monitor policy: {exc}"
            log.error(error)
        finally:
            try:
                self.plant.send_outputs(np.zeros(2))
                # A clean end leaves the node pre-operational (valves at zero) rather
                # than tripping its SYNC watchdog.
                self.plant.nmt(NmtCommand.ENTER_PRE_OPERATIONAL)
            except Exception:
                log.debug("could not zero the valves", exc_info=True)
            self._publish_status(finished=True)
        return RunResult(
            ticks=self.tick,
            sim_time_s=self.tick * ts,
            counters={
                **self.link.counters.as_dict(),
                **self.timing.as_dict(),
                **self.plant.counters.as_dict(),
                **self._events.as_dict(),
                **(self.faults.as_counters() if self.faults is not None else {}),
            },
            error=error,
            liveliness=self.liveliness,
        )

    def _emit_sync(self, tick: int) -> None:
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

    def _faulted_sample(self, faults: FaultStage, ts: float) -> tuple[int, ...] | None:
        """This tick's TPDO1 through the link faults: None when its SYNC or it was lost."""
        if not faults.expects_tpdo(self.tick):
            if not self.lockstep:
                self.plant.wait_tpdo(0.0)  # take what is on the bus (stale frames are counted there)
            return None
        words = self._lockstep_sample() if self.lockstep else self.plant.wait_tpdo(TPDO_WINDOW * ts)
        if words is None:
            return None
        delay = faults.tpdo(self.tick)
        if delay is None:
            return None
        if delay > 0:
            self.clock.wait(delay)
        return words

    def _lockstep_sample(self) -> tuple[int, ...]:
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
                raise PlantFault(f"plant did not answer SYNC at tick {self.tick} within {timeout:.1f} s")
            self.timing.sync_retries += 1
            self.plant.send_sync()
            retry = min(LOCKSTEP_RETRY_FRACTION * timeout, max(0.0, deadline - self.clock.now()))
            words = self.plant.wait_tpdo(retry)
            if words is not None:
                return words

    def _wait_for_dsp(self, stop: threading.Event, timeout: float) -> None:
        """Tell the DSP a new run starts (sequence numbers from 0, history
        restarted) and wait until a flag says it applied exactly that reset
        (``config_seq``) with an empty block expecting batch 0. The reset goes
        once the DSP is present (its subscriptions exist then) and again, with
        a new number, every ``RESET_RESEND_S`` while unanswered; so tick 0 never
        depends on when the DSP started or on message order."""
        deadline = self.clock.now() + timeout
        self.link.next_seq = 0
        reset_sent_at: float | None = None

        while not stop.is_set():
            now = self.clock.now()
            answered = reset_sent_at is not None and self._dsp_config_seq == self._config_seq and self.link.block_empty and self.link.next_seq == 0
            if answered or now >= deadline:
                break
            if self.dsp_alive and (reset_sent_at is None or now - reset_sent_at >= RESET_RESEND_S):
                self._send_reset()
                reset_sent_at = now
            event = self._next_event(0.05)
            if event is not None:
                self._take_event(*event)
            elif self.port.synchronous and not self.dsp_alive:
                break
        if not (self.link.block_empty and self.link.next_seq == 0 and self._dsp_config_seq == self._config_seq):
            log.warning("no DSP answered within %.1f s; controlling without identification until it does", timeout)
            if reset_sent_at is None:
                # Tell a DSP that turns up later all the same.
                self._send_reset()

    def _send_reset(self) -> None:
        """The run-start reset (a new number each time); after it, the next flag pairs."""
        self._config_seq += 1
        self._reset_sent = True
        self.link.next_seq = 0
        self.link.last_answered = None
        self.port.send_config(encode(ConfigChange(seq=self._config_seq, sim_time_s=0.0, reset=True)))

    def save(self, path: str, result: RunResult) -> None:
        """Write the run record (deterministic columns), timing and TF downloads."""
        metadata: dict[str, Any] = {"result": result.__dict__, "trajectory": self.law.trajectory.name}
        if isinstance(self.record, RowCounter) or isinstance(self.timing_record, RowCounter):
            raise ValueError("this run keeps no record: set RALF_RUN_RECORD to save one")
        if self.faults is not None:
            metadata["faults"] = {
                "scenario": self.faults.engine.scenario.model_dump(),
                "counters": self.faults.as_counters(),
                "events": [dataclasses.asdict(e) for e in self.faults.engine.events[:10000]],
            }
        self.record.save(path, self.settings.model_dump(), metadata)
        self.timing_record.save(path + ".timing", None, {"note": "wall-clock timing; differs run to run"})
        if not self.lockstep and self.hops.n:
            self._save_hops(path + ".hops.npz")
        if self.tf_snapshots:
            freqs = np.asarray(self.tf_snapshots[-1].freqs_hz)
            same = [s for s in self.tf_snapshots if len(s.freqs_hz) == freqs.size]
            columns: dict[str, np.ndarray] = {"sim_time_s": np.array([s.sim_time_s for s in same])}
            for name in ("H11", "H12", "H21", "H22", "Htot"):
                columns[f"{name}_mag"] = np.array([s.estimates[name].magnitude for s in same])
            arrays = {k: v for k, v in columns.items()}
            np.savez_compressed(path + ".tf.npz", freqs_hz=freqs, **arrays)  # type: ignore[arg-type]

    def _save_hops(self, path: str) -> None:
        """Real time: the tick path's raw per-hop stamps (wall clock, differs run to
        run; beside the timing record, never in the run record): per tick run, the
        last ``capacity`` of them in the order of the timing record's last rows, the
        wake-up lateness (ns, -1 not measured) and the stopwatch ns
        (``time.perf_counter_ns``: CLOCK_MONOTONIC, what ``perf record -k
        CLOCK_MONOTONIC`` stamps) of the SYNC sent, the TPDO1 in and the tick
        done, so an overrun can be set against a system trace."""
        hops = self.hops
        m = min(hops.n, hops.capacity)
        raw = np.frombuffer(hops.raw, dtype=np.int64)[: 4 * m].reshape(m, 4)
        if hops.n > hops.capacity:  # the ring wrapped: its oldest row is the next to be written
            raw = np.roll(raw, -(hops.n % hops.capacity), axis=0)
        np.savez(path, wakeup_ns=raw[:, 0], sync_ns=raw[:, 1], tpdo_ns=raw[:, 2], done_ns=raw[:, 3])

    def close(self) -> None:
        self.tf.join(timeout=3.0)
        self.port.close()
