"""The controller service: the emulated MVME CPU at the edge of CAN and zenoh.

Each tick (thesis §4, design.md "Time"):

1. SYNC -> the plant samples -> TPDO1 (A/D words);
2. flags and interrupts from the DSP are taken in; in lockstep the
   interrupt of the batch in flight is waited for at its due tick (the
   DSP's emulated latency in simulated time), so results do not depend on
   the host's load;
3. set-point -> OATF -> PI -> RPDO1 (D/A);
4. the sample joins the DSP link; a batch goes out when the block is empty;
5. transfer functions are downloaded every ``tf_download_samples``.

Real time: SYNC at absolute deadlines ``t0 + k Ts`` (no drift). Lockstep:
the next SYNC as soon as the tick is done.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from controller.dsp_link import DspLink
from controller.loop import ControlLaw, run_ticks
from controller.monitors import MonitorStop, Monitors
from controller.plant_link import PlantFault, PlantLink, StopRequested
from protocol.can_map import NmtCommand, NmtState
from controller.record import ColumnBuffer, save_record
from protocol.batch_codec import encode_batch
from protocol.encodings import BATCH, JSON
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import BlockFlag, ConfigChange, ControllerStatus, Health, Interrupt, TfSnapshot, decode, encode
from protocol.settings import ControllerSettings
from rig.runtime import HealthPublisher, LatencyTracker

log = logging.getLogger(__name__)

RESYNC_AFTER_PERIODS = 20
"""Real time: a loop this many periods late re-bases its schedule."""
LOCKSTEP_RETRY_S = 0.05
"""Lockstep: resend a SYNC that got no TPDO after this long (a lost frame)."""


@dataclass
class TimingCounters:
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

    def as_dict(self) -> dict[str, int]:
        return dict(vars(self))


@dataclass
class RunResult:
    ticks: int
    sim_time_s: float
    counters: dict[str, int]
    error: str | None = None
    liveliness: list[tuple[float, str, bool]] = field(default_factory=list)


class ControllerService:
    """Runs the loop against the plant (CAN) and the DSP (zenoh)."""

    def __init__(self, settings: ControllerSettings, session: zenoh.Session, plant: PlantLink, law: ControlLaw | None = None) -> None:
        self.settings = settings
        self.session = session
        self.plant = plant
        self.keys = Keys(settings.rig_id)
        self.law = law or ControlLaw(settings)
        self.link = DspLink(
            sample_rate_hz=settings.sample_rate_hz,
            batch_size=settings.batch_size,
            deadline_s=settings.dsp_deadline_s,
        )
        self.timing = TimingCounters()
        self.monitors = Monitors(
            {"deadline": settings.policy_deadline, "stale": settings.policy_stale, "dsp_lost": settings.policy_dsp_lost, "overrun": settings.policy_overrun}
        )
        self.tet = LatencyTracker()
        self.jitter = LatencyTracker()
        self.period_jitter = LatencyTracker()
        self.irq_latency = LatencyTracker()
        self.tick = 0
        self.latest_frequency_hz: float | None = None
        self.latest_interrupt: Interrupt | None = None
        self.last_fresh_tick = 0
        self.stale = False
        self.last_miss: str | None = None
        self.dsp_alive = False
        self.liveliness: list[tuple[float, str, bool]] = []
        self.tf_snapshots: list[TfSnapshot] = []
        self._last_words = np.zeros(4, dtype=np.int64)
        self._tf_thread: threading.Thread | None = None
        self._tf_due = False
        self._config_seq = -1
        self._events: queue.Queue[tuple[str, bytes, float]] = queue.Queue()
        self._irq_arrival: dict[int, float] = {}
        self._held_interrupts: list[Interrupt] = []
        self._batch_sent_wall: dict[int, float] = {}
        self._status_seq = 0
        self._last_status = 0.0
        self._rate_window: list[float] = []
        self.record = ColumnBuffer(
            {**{name: np.float64 for name in self._record_names()}, "tick": np.int64},
            capacity=4096,
        )
        self.timing_record = ColumnBuffer({"tick": np.int64, "sync_wall_s": np.float64, "tet_s": np.float64}, capacity=4096)
        block = zenoh.CongestionControl.BLOCK
        self._batch_pub = session.declare_publisher(self.keys.batch, encoding=BATCH, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._config_pub = session.declare_publisher(self.keys.dsp_config, encoding=JSON, congestion_control=block)
        self._status_pub = session.declare_publisher(self.keys.controller_status, encoding=JSON)
        self._tf_pub = session.declare_publisher(self.keys.tf_downloads, encoding=JSON)
        self._subs = [
            session.declare_subscriber(self.keys.flag, lambda s: self._events.put(("flag", s.payload.to_bytes(), time.monotonic()))),
            session.declare_subscriber(self.keys.interrupt, self._on_interrupt_sample),
            session.liveliness().declare_subscriber(self.keys.alive("dsp"), self._on_dsp_liveliness, history=True),
            session.declare_subscriber(self.keys.controller_command, lambda s: self._events.put(("command", s.payload.to_bytes(), time.monotonic()))),
        ]
        self._token = session.liveliness().declare_token(self.keys.alive("controller"))
        self._health = HealthPublisher(session, self.keys.health("controller"), settings.health_period_s, self._build_health)

    # -- bookkeeping --------------------------------------------------------------------
    def _record_names(self) -> list[str]:
        probe = self.law.record_row(0, self.law.step(0, np.zeros(4)))
        self.law.pi.reset()
        if self.law.oatf is not None:
            self.law.oatf.reset(self.law.setpoint(0) if self.settings.oatf_location == "outer" else 0.0)
        return [k for k in probe if k != "tick"] + ["irq_applied", "stale", "f_id_hz", "f_id2_hz", "zeta_id", "id_confidence"]

    def _on_interrupt_sample(self, sample: zenoh.Sample) -> None:
        """Stamp the interrupt's arrival here: the MVME took it as a hardware
        interrupt, not at the next tick."""
        self._events.put(("interrupt", sample.payload.to_bytes(), time.monotonic()))

    def _on_dsp_liveliness(self, sample: zenoh.Sample) -> None:
        up = sample.kind == zenoh.SampleKind.PUT
        self._events.put(("alive", b"1" if up else b"0", time.monotonic()))

    def _build_health(self, seq: int) -> Health:
        counters = {**self.plant.counters.as_dict(), **self.link.counters.as_dict(), **self.timing.as_dict()}
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
            },
            last_miss=self.monitors.last or self.last_miss,
        )

    def _publish_status(self, finished: bool = False) -> None:
        now = time.monotonic()
        if not finished and now - self._last_status < 0.25:
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
        self._status_pub.put(encode(status))

    # -- DSP side -----------------------------------------------------------------------
    def _take_event(self, kind: str, payload: bytes, arrival: float) -> None:
        try:
            if kind == "flag":
                self.link.on_flag(decode(BlockFlag, payload))
            elif kind == "interrupt":
                irq = decode(Interrupt, payload)
                self._irq_arrival[irq.batch_seq] = arrival
                self._held_interrupts.append(irq)
            elif kind == "command":
                self.reconfigure(decode(ConfigChange, payload))
            elif kind == "alive":
                up = payload == b"1"
                if up != self.dsp_alive:
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

    def reconfigure(self, change: ConfigChange) -> None:
        """A run-time command (thesis §3.2.3): the batch size applies here
        from the next batch on; the FFT width, alpha and latency go to the
        DSP, which zeroes its history on an FFT-width change."""
        if change.batch_size is not None:
            log.info("batch size %d -> %d", self.link.batch_size, change.batch_size)
            self.link.batch_size = change.batch_size
        self._config_seq += 1
        forwarded = change.model_copy(update={"seq": self._config_seq, "sim_time_s": self.tick * self.settings.sample_period_s})
        self._config_pub.put(encode(forwarded))
        self.timing.reconfigurations += 1

    def _drain_events(self) -> None:
        while True:
            try:
                kind, payload, arrival = self._events.get_nowait()
            except queue.Empty:
                return
            self._take_event(kind, payload, arrival)

    def _wait_for_interrupt(self, seq: int) -> None:
        """Lockstep: block until the interrupt of batch ``seq`` is in (or time out)."""
        deadline = time.monotonic() + self.settings.lockstep_timeout_s
        self.timing.lockstep_waits += 1
        while not any(irq.batch_seq == seq for irq in self._held_interrupts):
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                # It will not come: count it lost, fire the deadline monitor, go on without it.
                self.link.declare_lost()
                self.last_miss = f"batch {seq}: no interrupt within {self.settings.lockstep_timeout_s:.1f} s (lockstep); declared lost"
                self.monitors.fire("deadline", self.last_miss)
                return
            if not self.dsp_alive and self.timing.dsp_found:
                return
            try:
                kind, payload, arrival = self._events.get(timeout=min(remaining, 0.1))
            except queue.Empty:
                continue
            self._take_event(kind, payload, arrival)

    def _apply_interrupts(self) -> bool:
        """Apply held interrupts that are due; True if one was applied this tick."""
        lockstep = self.settings.clock == "lockstep"
        sent = self.link.in_flight
        if lockstep and sent is not None and self.tick >= sent.due_tick and self.dsp_alive:
            self._wait_for_interrupt(sent.seq)
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
            arrived = self._irq_arrival.pop(irq.batch_seq, time.monotonic())
            if sent_wall is not None:
                self.irq_latency.add(arrived - sent_wall)
            self.timing.interrupts_applied += 1
            applied = True
            if not self.link.missed_current:
                self.monitors.clear("deadline")
            self.latest_interrupt = irq
            if irq.poles:
                self.latest_frequency_hz = irq.poles[0].frequency_hz
            if irq.poles and irq.confidence >= self.settings.oatf_min_confidence:
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
        batch = type(batch)(**{**batch.__dict__, "wall_time_s": time.time()})
        self._batch_sent_wall[sent.seq] = time.monotonic()
        self._batch_pub.put(encode_batch(batch))

    def _download_tf(self) -> None:
        try:
            replies = list(self.session.get(self.keys.tf, timeout=2.0))
        except Exception as exc:  # a dying session must not end the run
            self.timing.tf_download_failures += 1
            log.warning("TF download failed: %s", exc)
            return
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                payload = reply.ok.payload.to_bytes()
                self.tf_snapshots.append(decode(TfSnapshot, payload))
                self.timing.tf_downloads += 1
                self._tf_pub.put(payload)  # controller/tf: each download, for recorders and viewers
                return
            except ProtocolError as exc:
                self.timing.undecodable += 1
                log.warning("bad TF snapshot: %s", exc)
        self.timing.tf_download_failures += 1

    def _check_stale(self) -> None:
        """Stale: no fresh confident estimate for ``stale_after_s``. Before the
        first one, the clock starts once the DSP's history can be full (N
        samples): no estimate can exist earlier."""
        if self.last_fresh_tick == 0 and self.tick < self.link.dsp_fft_width:
            return
        start = self.last_fresh_tick or self.link.dsp_fft_width
        age = (self.tick - start) * self.settings.sample_period_s
        stale = age > self.settings.stale_after_s
        if stale and not self.stale:
            self.timing.stale_episodes += 1
            self.last_miss = f"parameters stale at tick {self.tick} ({age:.2f} s without a fresh estimate)"
            self.monitors.fire("stale", self.last_miss)
        elif self.stale and not stale:
            self.monitors.clear("stale")
        self.stale = stale
        self.timing.stale_ticks += int(stale)

    # -- the loop -----------------------------------------------------------------------
    def _tick(self, words: np.ndarray) -> None:
        self._drain_events()
        applied = self._apply_interrupts()
        out = self.law.step(self.tick, words)
        self.plant.send_outputs(out.volts)
        self.link.add_sample(self.tick, out.volts, out.measurement.deflection_in)
        if self.settings.tf_download_samples and self.tick > 0 and self.tick % self.settings.tf_download_samples == 0:
            self._tf_due = True
        if self._tf_due and self.dsp_alive:
            if self.settings.clock == "lockstep":
                if self.link.in_flight is None:  # the DSP is idle: the snapshot is deterministic
                    self._tf_due = False
                    self._download_tf()
            elif self._tf_thread is None or not self._tf_thread.is_alive():
                # real time: the query must not hold up the loop
                self._tf_due = False
                self._tf_thread = threading.Thread(target=self._download_tf, name="tf-download", daemon=True)
                self._tf_thread.start()
            else:
                self._tf_due = False
                self.timing.tf_download_failures += 1  # the previous download is still under way
        self._maybe_send_batch()
        if self.link.check_deadline(self.tick):
            self.last_miss = f"batch {self.link.in_flight.seq if self.link.in_flight else '?'}: no interrupt within {self.link.deadline * 1e3:.0f} ms"
            self.monitors.fire("deadline", self.last_miss)
        self._check_stale()
        self.law.set_degraded(self.monitors.degraded)
        row = self.law.record_row(self.tick, out)
        row["irq_applied"] = float(applied)
        row["stale"] = float(self.stale)
        irq = self.latest_interrupt
        poles = irq.poles if irq is not None else ()
        row["f_id_hz"] = poles[0].frequency_hz if poles else float("nan")
        row["f_id2_hz"] = poles[1].frequency_hz if len(poles) > 1 else float("nan")
        row["zeta_id"] = poles[0].damping_ratio if poles else float("nan")
        row["id_confidence"] = irq.confidence if irq is not None else 0.0
        self.record.append(row)

    def run(self, stop: threading.Event) -> RunResult:
        """Start the plant node and run until the duration, the trajectory's
        end, ``stop``, or a plant fault."""
        s = self.settings
        self._health.start()
        error: str | None = None
        n_ticks = run_ticks(s, self.law.lap_ticks)
        ts = s.sample_period_s
        lockstep = s.clock == "lockstep"
        try:
            self.plant.start_node(timeout=s.lockstep_timeout_s, stop=stop, sample_period_s=ts)
            self._wait_for_dsp(stop, timeout=3.0)
            t0 = time.monotonic()
            missed_in_row = 0
            last_start: float | None = None
            while not stop.is_set() and (n_ticks is None or self.tick < n_ticks):
                if s.inject_stall_at_s is not None and self.tick == int(round(s.inject_stall_at_s * s.sample_rate_hz)):
                    log.warning("fault injection: the loop stalls for %.2f s", s.inject_stall_s)
                    time.sleep(s.inject_stall_s)
                scheduled = t0 + self.tick * ts
                if not lockstep and time.monotonic() - scheduled > RESYNC_AFTER_PERIODS * ts:
                    # Hopelessly behind (a stall, or a rate the host cannot hold): those
                    # sample instants are gone. Skip them (counted) instead of running
                    # ticks back to back; the DSP sees the gap and restarts its history.
                    behind = int((time.monotonic() - scheduled) / ts)
                    self.tick += behind
                    scheduled += behind * ts
                    self.timing.schedule_resyncs += 1
                    self.timing.periods_skipped += behind
                    log.warning("loop %d periods late: schedule re-based, samples skipped", behind)
                    if n_ticks is not None and self.tick >= n_ticks:
                        break
                if not lockstep:
                    delay = scheduled - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                start = time.monotonic()
                if s.inject_sync_drop_every and self.tick % s.inject_sync_drop_every == s.inject_sync_drop_every - 1:
                    self.plant.skip_sync()  # counter advances, frame never sent: the node sees the gap
                    self.timing.syncs_dropped += 1
                self.plant.send_sync()
                if not lockstep:
                    self.jitter.add(max(0.0, start - scheduled))  # lateness of this SYNC against its deadline
                    if last_start is not None:
                        self.period_jitter.add(abs(start - last_start - ts))
                    last_start = start
                words = self._lockstep_sample() if lockstep else self.plant.wait_tpdo(0.8 * ts)
                if words is None:
                    missed_in_row += 1
                    if self.plant.heartbeat_age() > s.plant_heartbeat_timeout_s or missed_in_row * ts > s.plant_heartbeat_timeout_s:
                        raise PlantFault(f"plant did not answer SYNC at tick {self.tick}: {missed_in_row} TPDOs missing in a row (heartbeat age {self.plant.heartbeat_age():.2f} s)")
                    words = self._last_words  # real time: hold the last sample for a missed TPDO
                else:
                    missed_in_row = 0
                self._last_words = words
                self._tick(words)
                end = time.monotonic()
                self.tet.add(end - start)
                self.timing_record.append(tick=self.tick, sync_wall_s=start - t0, tet_s=end - start)
                if not lockstep and end > scheduled + ts:
                    self.timing.overruns += 1
                    self.monitors.fire("overrun", f"tick {self.tick} took {(end - start) * 1e3:.2f} ms, past the next SYNC")
                elif "overrun" in self.monitors.active:
                    self.monitors.clear("overrun")
                self.tick += 1
                self._rate_window.append(end)
                if len(self._rate_window) > 200:
                    del self._rate_window[0]
                if self.plant.heartbeat_age() > s.plant_heartbeat_timeout_s:
                    raise PlantFault(f"plant heartbeat lost for {self.plant.heartbeat_age():.2f} s")
                if self.plant.node_state not in (None, NmtState.OPERATIONAL):
                    raise PlantFault(f"plant node left OPERATIONAL (heartbeat says {self.plant.node_state.name})")
                self._publish_status()
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
            counters={**self.link.counters.as_dict(), **self.timing.as_dict(), **self.plant.counters.as_dict()},
            error=error,
            liveliness=self.liveliness,
        )

    def _lockstep_sample(self) -> np.ndarray:
        """Lockstep: the TPDO for this tick. A SYNC lost on the bus gets no
        answer; after ``LOCKSTEP_RETRY_S`` the SYNC is sent again (the node
        sees a counter gap and steps once), until ``lockstep_timeout_s``."""
        deadline = time.monotonic() + self.settings.lockstep_timeout_s
        while True:
            words = self.plant.wait_tpdo(min(LOCKSTEP_RETRY_S, max(0.0, deadline - time.monotonic())))
            if words is not None:
                return words
            if time.monotonic() >= deadline:
                raise PlantFault(f"plant did not answer SYNC at tick {self.tick} within {self.settings.lockstep_timeout_s:.1f} s")
            self.timing.sync_retries += 1
            self.plant.send_sync()

    def _wait_for_dsp(self, stop: threading.Event, timeout: float) -> None:
        """Tell the DSP a new run starts (sequence numbers from 0, history
        restarted) and give it a moment to announce its empty block."""
        self._config_seq += 1
        self._config_pub.put(encode(ConfigChange(seq=self._config_seq, sim_time_s=0.0, reset=True)))
        self.link.next_seq = 0
        deadline = time.monotonic() + timeout
        while not self.link.block_empty and time.monotonic() < deadline and not stop.is_set():
            try:
                kind, payload, arrival = self._events.get(timeout=0.05)
            except queue.Empty:
                continue
            self._take_event(kind, payload, arrival)
        if not self.link.block_empty:
            log.warning("no DSP answered within %.1f s; controlling without identification until it does", timeout)

    def save(self, path: str, result: RunResult) -> None:
        """Write the run record (deterministic columns), timing and TF downloads."""
        metadata: dict[str, Any] = {"result": result.__dict__, "trajectory": self.law.trajectory.name}
        save_record(path, self.record.to_columns(), self.settings.model_dump(), metadata)
        save_record(path + ".timing", self.timing_record.to_columns(), None, {"note": "wall-clock timing; differs run to run"})
        if self.tf_snapshots:
            freqs = np.asarray(self.tf_snapshots[-1].freqs_hz)
            same = [s for s in self.tf_snapshots if len(s.freqs_hz) == freqs.size]
            columns: dict[str, np.ndarray] = {"sim_time_s": np.array([s.sim_time_s for s in same])}
            for name in ("H11", "H12", "H21", "H22", "Htot"):
                columns[f"{name}_mag"] = np.array([s.estimates[name].magnitude for s in same])  # type: ignore[index]
            arrays = {k: v for k, v in columns.items()}
            np.savez_compressed(path + ".tf.npz", freqs_hz=freqs, **arrays)

    def close(self) -> None:
        if self._tf_thread is not None:
            self._tf_thread.join(timeout=3.0)
        self._health.stop()
        for sub in self._subs:
            sub.undeclare()
        self._token.undeclare()
        for pub in (self._batch_pub, self._config_pub, self._status_pub, self._tf_pub):
            pub.undeclare()

