"""The DSP service: the emulated C40 board on zenoh.

Subscribes to sample batches and run-time configuration, runs one
identification step per batch, and answers with the block flag and the
interrupt carrying the pole parameters (thesis §3.2.3, Fig. 3.5). Heavy
work happens on the service's own thread, never in zenoh callbacks.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from dsp_service.board import Admission, BatchBlock
from dsp_service.identifier import IdentificationResult, Identifier, IdentifierConfig
from protocol.batch_codec import SampleBatch, decode_batch
from protocol.encodings import JSON
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import (
    BlockFlag,
    ConfigChange,
    Health,
    Interrupt,
    PoleParameters,
    TfSnapshot,
    TransferFunction,
    decode,
    encode,
)
from protocol.settings import DspSettings
from rig.runtime import HealthPublisher, LatencyTracker

log = logging.getLogger(__name__)

_TF_NAMES = ("H11", "H12", "H21", "H22", "Htot")


def identifier_config(settings: DspSettings) -> IdentifierConfig:
    """The identifier's configuration from the service settings."""
    return IdentifierConfig(
        sample_rate_hz=settings.sample_rate_hz,
        fft_width=settings.fft_width,
        averaging=settings.averaging,
        alpha=settings.alpha,
        rls_forgetting=1.0 - settings.alpha,
        solver=settings.solver,
        smoothing_window=settings.smoothing_window,
        smoothing_order=settings.smoothing_order,
        search_min_hz=settings.search_min_hz,
        search_max_hz=min(settings.search_max_hz, settings.sample_rate_hz / 2),
    )


@dataclass
class _Event:
    kind: str
    payload: bytes = b""
    batch: SampleBatch | None = None
    admission: Admission | None = None


class DspService:
    """The board: batch block, identifier, publishers, health."""

    def __init__(self, settings: DspSettings, session: zenoh.Session) -> None:
        self.settings = settings
        self.session = session
        self.keys = Keys(settings.rig_id)
        self.identifier = Identifier(identifier_config(settings))
        self.block = BatchBlock()
        self.batch_size = settings.batch_size
        self.emulated_latency_s = settings.emulated_latency_s
        self.extra_delay_s = settings.inject_delay_s
        self.compute_time = LatencyTracker()
        self.turnaround = LatencyTracker()
        self.interrupt_seq = 0
        self.flag_seq = 0
        self.tf_seq = 0
        self.last_batch_seq = 0
        self.last_sim_time = 0.0
        self.last_result: IdentificationResult | None = None
        self.last_batch_missed = False
        self._events: queue.Queue[_Event] = queue.Queue()
        self._tf_lock = threading.Lock()
        self._block_lock = threading.Lock()
        block = zenoh.CongestionControl.BLOCK
        self._flag_pub = session.declare_publisher(self.keys.flag, encoding=JSON, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._irq_pub = session.declare_publisher(self.keys.interrupt, encoding=JSON, congestion_control=block, priority=zenoh.Priority.REAL_TIME, express=True)
        self._subs = [
            session.declare_subscriber(self.keys.batch, self._on_batch_sample),
            session.declare_subscriber(self.keys.dsp_config, lambda s: self._events.put(_Event("config", s.payload.to_bytes()))),
        ]
        self._queryable = session.declare_queryable(self.keys.tf, self._on_tf_query)
        self._token = session.liveliness().declare_token(self.keys.alive("dsp"))
        self._health = HealthPublisher(session, self.keys.health("dsp"), settings.health_period_s, self._build_health)

    # -- budget ---------------------------------------------------------------------
    def budget_s(self, batch: SampleBatch) -> float:
        """Compute budget for a batch: configured, else the nominal batch
        period ``l / fs`` (the deadline the thesis names: the CPU's next batch
        is due then). Not the batch's own length: batches grow while the
        board is late, which would excuse the lateness."""
        return self.settings.budget_s or self.batch_size / batch.sample_rate_hz

    # -- messages out -----------------------------------------------------------------
    def _publish_flag(self, state: str) -> None:
        flag = BlockFlag(
            seq=self.flag_seq,
            sim_time_s=self.last_sim_time,
            state=state,  # type: ignore[arg-type]
            next_batch_seq=self.block.next_seq,
            fft_width=self.identifier.fft_width,
            batch_size=self.batch_size,
            emulated_latency_s=self.emulated_latency_s,
        )
        self.flag_seq += 1
        self._flag_pub.put(encode(flag))

    def _build_health(self, seq: int) -> Health:
        counters = self.block.counters.as_dict()
        counters["interrupts"] = self.interrupt_seq
        state = "degraded" if self.last_batch_missed else "running"
        return Health(
            seq=seq,
            sim_time_s=self.last_sim_time,
            service="dsp",
            state=state,  # type: ignore[arg-type]
            counters=counters,
            latencies={"compute": self.compute_time.stats(), "batch_to_interrupt": self.turnaround.stats()},
            last_miss=self.block.last_violation,
        )

    # -- handlers -----------------------------------------------------------------------
    def _reject(self, reason: str) -> None:
        with self._block_lock:
            self.block.counters.rejected += 1
            self.block.last_violation = reason
        log.warning("rejected a batch: %s", reason)

    def _on_batch_sample(self, sample: zenoh.Sample) -> None:
        """A batch arrives in the block (zenoh's thread): decoded, checked and
        admitted here, so a batch arriving while the block is full is seen as
        the protocol violation it is; the identification runs on our thread."""
        try:
            batch = decode_batch(sample.payload.to_bytes())
        except ProtocolError as exc:
            with self._block_lock:
                self.block.counters.decode_errors += 1
                self.block.last_violation = f"undecodable batch: {exc}"
            log.warning("dropped an undecodable batch: %s", exc)
            return
        if batch.inputs.shape[0] != 2 or batch.outputs.shape[0] != 2:
            self._reject(f"batch {batch.seq} has {batch.inputs.shape[0]} inputs and {batch.outputs.shape[0]} outputs; the board identifies 2x2")
            return
        if abs(batch.sample_rate_hz - self.settings.sample_rate_hz) > 1e-9 * self.settings.sample_rate_hz:
            self._reject(f"batch {batch.seq} sampled at {batch.sample_rate_hz} Hz; this board runs at {self.settings.sample_rate_hz} Hz")
            return
        with self._block_lock:
            admission = self.block.admit(batch)
        if admission.accepted:
            self._events.put(_Event("batch", batch=batch, admission=admission))
    def _on_tf_query(self, query: zenoh.Query) -> None:
        try:
            query.reply(self.keys.tf, encode(self.snapshot()), encoding=JSON)
        except Exception as exc:  # never let a query kill zenoh's thread
            log.exception("TF query failed")
            query.reply_err(str(exc).encode())

    def snapshot(self) -> TfSnapshot:
        """The current transfer-function estimates (magnitude and phase)."""
        with self._tf_lock:
            tf = self.identifier.transfer_functions()
            estimates = {}
            for name in _TF_NAMES:
                h = np.nan_to_num(np.asarray(getattr(tf, name)), nan=0.0, posinf=0.0, neginf=0.0)
                estimates[name] = TransferFunction(magnitude=tuple(np.abs(h).tolist()), phase_rad=tuple(np.angle(h).tolist()))
            snap = TfSnapshot(
                seq=self.tf_seq,
                sim_time_s=self.last_sim_time,
                batch_seq=self.last_batch_seq,
                freqs_hz=tuple(np.asarray(tf.freqs_hz, dtype=float).tolist()),
                valid=tuple(bool(v) for v in np.asarray(tf.valid)),
                estimates=estimates,  # type: ignore[arg-type]
            )
            self.tf_seq += 1
            return snap

    def apply_config(self, change: ConfigChange) -> None:
        """Run-time configuration; ``reset`` starts a new CPU run (sequence
        numbers from 0, history restarted, averages kept)."""
        if change.reset:
            with self._block_lock:
                self.block.restart()
        with self._tf_lock:
            if change.reset:
                self.identifier.restart_history()
            if change.fft_width is not None and change.fft_width != self.identifier.fft_width:
                log.info("FFT width %d -> %d: history zeroed", self.identifier.fft_width, change.fft_width)
                self.identifier.set_fft_width(change.fft_width)
            if change.batch_size is not None:
                self.batch_size = change.batch_size
            if change.alpha is not None:
                self.identifier.set_alpha(change.alpha)
            if change.emulated_latency_s is not None:
                self.emulated_latency_s = change.emulated_latency_s
        self.block.note_config(change)

    def process_batch(self, batch: SampleBatch, admission: Admission | None = None) -> Interrupt | None:
        """One pass of Fig. 3.5 steps 3-4 for a batch (admitted here unless
        it already was on arrival)."""
        if admission is None:
            with self._block_lock:
                admission = self.block.admit(batch)
        if not admission.accepted:
            return None
        received = time.monotonic()
        self.last_sim_time = batch.sim_time_s + batch.n_samples / batch.sample_rate_hz
        self.last_batch_seq = batch.seq
        started = time.perf_counter()
        with self._tf_lock:
            if admission.restart_history:
                self.identifier.restart_history()
            self.identifier.push(batch.inputs, batch.outputs)
            result = self.identifier.step()
        if self.extra_delay_s > 0:  # fault injection: a slowed board
            time.sleep(self.extra_delay_s)
        compute = time.perf_counter() - started
        self.compute_time.add(compute)
        budget = self.budget_s(batch)
        missed = compute > budget
        if missed:
            self.block.counters.budget_misses += 1
            self.block.last_violation = f"batch {batch.seq}: compute {compute * 1e3:.1f} ms over budget {budget * 1e3:.1f} ms"
            log.warning("deadline: %s", self.block.last_violation)
        self.last_result = result
        self.last_batch_missed = missed
        if self.settings.clock == "realtime":
            remaining = self.emulated_latency_s - (time.monotonic() - received)
            if remaining > 0:
                time.sleep(remaining)
        interrupt = Interrupt(
            seq=self.interrupt_seq,
            sim_time_s=self.last_sim_time,
            batch_seq=batch.seq,
            poles=tuple(
                PoleParameters(frequency_hz=p.frequency_hz, damping_ratio=max(p.damping_ratio, 0.0), magnitude=p.magnitude, source=p.source)
                for p in result.poles
                if np.isfinite(p.frequency_hz) and p.frequency_hz > 0 and np.isfinite(p.damping_ratio) and np.isfinite(p.magnitude)
            ),
            confidence=float(np.clip(result.confidence, 0.0, 1.0)),
            compute_time_s=compute,
            emulated_latency_s=self.emulated_latency_s,
            samples_in_history=result.samples_in_history,
            valid_fraction=float(np.clip(result.valid_fraction, 0.0, 1.0)),
            deadline_missed=missed,
        )
        self.interrupt_seq += 1
        with self._block_lock:
            self.block.release()
        self._publish_flag("empty")
        self._irq_pub.put(encode(interrupt))
        self.turnaround.add(time.monotonic() - received)
        return interrupt

    def _handle(self, event: _Event) -> None:
        if event.kind == "batch" and event.batch is not None:
            self.process_batch(event.batch, event.admission)
        elif event.kind == "config":
            try:
                change = decode(ConfigChange, event.payload)
            except ProtocolError as exc:
                self.block.counters.decode_errors += 1
                log.warning("dropped an invalid config change: %s", exc)
                return
            try:
                self.apply_config(change)
            except ValueError as exc:
                self.block.counters.config_rejected += 1
                self.block.last_violation = f"config change refused: {exc}"
                log.warning("refused a config change the identifier cannot take: %s", exc)
            self._publish_flag("empty" if not self.block.full else "full")

    def _handle_safely(self, event: _Event) -> None:
        """Nothing a peer sends may kill the board: an unexpected error is
        counted and reported, and the block is released so the CPU goes on."""
        try:
            self._handle(event)
        except Exception as exc:
            self.block.counters.internal_errors += 1
            self.block.last_violation = f"internal error on a {event.kind}: {exc!r}"
            log.exception("internal error while handling a %s; block released", event.kind)
            with self._block_lock:
                self.block.release()
            self._publish_flag("empty")

    def run(self, stop: threading.Event) -> None:
        """Serve until ``stop`` is set."""
        self._health.start()
        self._publish_flag("empty")  # Fig. 3.5 step 1: the block starts empty
        last_flag = time.monotonic()
        while not stop.is_set():
            try:
                event = self._events.get(timeout=0.05)
            except queue.Empty:
                # Re-announce an empty block now and then, so a controller that
                # starts after us (or missed the first flag) learns it.
                if not self.block.full and time.monotonic() - last_flag > 0.5:
                    self._publish_flag("empty")
                    last_flag = time.monotonic()
                continue
            self._handle_safely(event)
            last_flag = time.monotonic()

    def close(self) -> None:
        self._health.stop()
        for sub in self._subs:
            sub.undeclare()
        self._queryable.undeclare()
        self._token.undeclare()
        self._flag_pub.undeclare()
        self._irq_pub.undeclare()
