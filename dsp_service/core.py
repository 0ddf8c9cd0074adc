"""The C40 board without its transport: batch block, identifier, block flag
and interrupt (thesis §3.2.3, Fig. 3.5 steps 1-4), as one deterministic core.

No zenoh, no threads, no clock of its own: the zenoh service
(:mod:`dsp_service.service`) and the one-thread co-simulation
(:mod:`workbench.cosim`) both drive it, so both identify with the same code. The
compute time of a step is measured with the injected ``perf_counter`` (it
goes into the interrupt's ``compute_time_s`` and the budget check only; no
estimate depends on it).

Time
    The board's emulated latency is a *due time*, never a sleep: after
    :meth:`DspCore.process` the block stays full and the interrupt is held
    until :meth:`DspCore.due_after` has passed on the caller's scheduler;
    then :meth:`DspCore.release` flags the block empty. In lockstep and
    co-simulation the controller applies the latency in simulated ticks
    (the flag announces it), so the board releases at once.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any, Literal, NamedTuple

import numpy as np

from dsp_service.board import Admission, BatchBlock
from dsp_service.identifier import IdentificationResult, Identifier, IdentifierConfig
from protocol.batch_codec import SampleBatch
from protocol.messages import INTERRUPT_VERSION, BlockFlag, ConfigAck, ConfigChange, Interrupt, TfSnapshot, TransferFunction
from protocol.settings import DspSettings
from service_kit.inbox import RateLimitedLog
from service_kit.link_faults import scenario_setting

log = logging.getLogger(__name__)
_log_once = RateLimitedLog(log)  # a flood of bad batches logs once per 10 s (counted all the same)

#: The estimates a TfSnapshot carries (the keys of ``TfSnapshot.estimates``).
TfName = Literal["H11", "H12", "H21", "H22", "Htot"]
TF_NAMES: tuple[TfName, ...] = ("H11", "H12", "H21", "H22", "Htot")
#: ``BlockFlag.state``.
BlockState = Literal["empty", "full"]


class FlagState(NamedTuple):
    """The fields of a :class:`BlockFlag`, taken when the block changed."""

    seq: int
    sim_time_s: float
    state: BlockState
    next_batch_seq: int
    fft_width: int
    batch_size: int
    emulated_latency_s: float
    config_seq: int | None


MAX_EMULATED_LATENCY_S = 10.0
"""A run-time ConfigChange may not set a longer emulated latency than the
setting allows (``emulated_latency_s`` is capped at 10 s there too)."""


def identifier_config(settings: DspSettings) -> IdentifierConfig:
    """The identifier's configuration from the service settings."""
    return IdentifierConfig(
        sample_rate_hz=settings.sample_rate_hz,
        fft_width=settings.fft_width,
        averaging=settings.averaging,
        method=settings.identifier,
        arx_regime_bank=settings.arx_regime_bank,
        alpha=settings.alpha,
        rls_forgetting=1.0 - settings.alpha,
        solver=settings.solver,
        smoothing_window=settings.smoothing.window,
        smoothing_order=settings.smoothing.order,
        search_min_hz=settings.search_band_hz[0],
        search_max_hz=min(settings.search_band_hz[1], settings.sample_rate_hz / 2),
    )


class DspCore:
    """Block, identifier and the messages the board answers with."""

    def __init__(self, settings: DspSettings, perf_counter: Callable[[], float] = time.perf_counter) -> None:
        self.settings = settings
        self.identifier = Identifier(identifier_config(settings))
        self.block = BatchBlock()
        self.batch_size = settings.batch_size
        self.emulated_latency_s = settings.emulated_latency_s
        scenario = scenario_setting(settings.fault_scenario)
        self.extra_delay_s = scenario.dsp_delay_s if scenario is not None else 0.0
        self.perf_counter = perf_counter
        self.interrupt_seq = 0
        self.flag_seq = 0
        self.tf_seq = 0
        self.last_batch_seq = 0
        self.last_sim_time = 0.0
        self.last_result: IdentificationResult | None = None
        self.last_batch_missed = False
        self.config_seq: int | None = None
        """seq of the last ConfigChange applied (announced in every flag)."""
        self.block_lock = threading.Lock()
        """Held around block changes: a zenoh callback admits while the board's thread releases."""
        self.tf_lock = threading.Lock()
        """Held around the identifier: a TF query may come on zenoh's thread."""

    # -- admission ------------------------------------------------------------------
    def check(self, batch: SampleBatch) -> str | None:
        """Why this board cannot identify ``batch`` (None: it can)."""
        if batch.inputs.shape[0] != 2 or batch.outputs.shape[0] != 2:
            return f"batch {batch.seq} has {batch.inputs.shape[0]} inputs and {batch.outputs.shape[0]} outputs; the board identifies 2x2"
        if abs(batch.sample_rate_hz - self.settings.sample_rate_hz) > 1e-9 * self.settings.sample_rate_hz:
            return f"batch {batch.seq} sampled at {batch.sample_rate_hz} Hz; this board runs at {self.settings.sample_rate_hz} Hz"
        return None

    def reject(self, reason: str) -> None:
        with self.block_lock:
            self.block.counters.rejected += 1
            self.block.last_violation = reason
        _log_once.warning("rejected", "rejected a batch: %s", reason)

    def admit(self, batch: SampleBatch) -> Admission:
        """Check and admit an arriving batch (marks the block full when accepted)."""
        reason = self.check(batch)
        if reason is not None:
            self.reject(reason)
            return Admission(False, reason=reason)
        with self.block_lock:
            return self.block.admit(batch)

    # -- budget and due time ---------------------------------------------------------
    def budget_s(self, batch: SampleBatch) -> float:
        """Compute budget for a batch: configured, else the nominal batch
        period ``l / fs`` (the deadline the thesis names: the CPU's next batch
        is due then). Not the batch's own length: batches grow while the
        board is late, which would excuse the lateness."""
        return self.settings.budget_s or self.batch_size / batch.sample_rate_hz

    def due_after(self, compute_time_s: float, realtime: bool) -> float:
        """Seconds after the batch arrived at which its interrupt is raised:
        the emulated latency in real time (the C40's compute time), and in
        every mode at least the compute time (an injected slow board included)."""
        latency = self.emulated_latency_s if realtime else 0.0
        return max(latency, compute_time_s)

    # -- the step ------------------------------------------------------------------------
    def process(self, batch: SampleBatch, admission: Admission) -> Interrupt:
        """Fig. 3.5 step 3: identify an admitted batch; returns the interrupt
        (the block stays full until :meth:`release`)."""
        return Interrupt(**self.process_fields(batch, admission))

    def process_fields(self, batch: SampleBatch, admission: Admission) -> dict[str, Any]:
        """:meth:`process`, returning the interrupt's fields unvalidated: every
        field of :class:`Interrupt` in its order, as plain Python values, so
        :func:`protocol.messages.encode_fields` gives the interrupt's bytes
        without building the model first (the service puts them and validates
        the model after the put; the batch -> interrupt path is shorter by
        the model's construction and encode)."""
        self.last_sim_time = batch.sim_time_s + batch.n_samples / batch.sample_rate_hz
        self.last_batch_seq = batch.seq
        started = self.perf_counter()
        with self.tf_lock:
            if admission.restart_history:
                self.identifier.restart_history()
            self.identifier.push(batch.inputs, batch.outputs)
            result = self.identifier.step()
        compute = self.perf_counter() - started + self.extra_delay_s  # fault injection: a slowed board
        budget = self.budget_s(batch)
        missed = compute > budget
        if missed:
            self.block.counters.budget_misses += 1
            self.block.last_violation = f"batch {batch.seq}: compute {compute * 1e3:.1f} ms over budget {budget * 1e3:.1f} ms"
            log.warning("deadline: %s", self.block.last_violation)
        self.last_result = result
        self.last_batch_missed = missed
        # Scalars clamped with math and min/max, not numpy's scalar ufuncs (np.clip on a
        # scalar costs ~9 us, on the batch -> interrupt path); the same values, NaN and
        # -0.0 included (the interrupt's validation refuses a NaN either way).
        isfinite = math.isfinite
        fields = {
            "seq": self.interrupt_seq,
            "sim_time_s": self.last_sim_time,
            "wall_time_s": time.time(),
            "version": INTERRUPT_VERSION,
            "batch_seq": batch.seq,
            # the poles as dicts, as PoleParameters orders its fields (validated into
            # PoleParameters in the Interrupt's one validation call when the model is built)
            "poles": [
                {
                    "frequency_hz": float(p.frequency_hz),
                    "damping_ratio": float(max(p.damping_ratio, 0.0)),
                    "magnitude": float(p.magnitude),
                    "source": p.source,
                    "confidence": float(min(max(p.confidence, 0.0), 1.0)),
                }
                for p in result.poles
                if isfinite(p.frequency_hz) and p.frequency_hz > 0 and isfinite(p.damping_ratio) and isfinite(p.magnitude)
            ],
            "confidence": float(min(max(result.confidence, 0.0), 1.0)),
            "compute_time_s": compute,
            "emulated_latency_s": self.emulated_latency_s,
            "samples_in_history": int(result.samples_in_history),
            "valid_fraction": float(min(max(result.valid_fraction, 0.0), 1.0)),
            "deadline_missed": bool(missed),
        }
        self.interrupt_seq += 1
        return fields

    def release(self) -> BlockFlag:
        """Fig. 3.5 step 4: the block is empty again; returns the flag to publish."""
        return self.flag_of(self.release_state())

    def release_state(self) -> FlagState:
        """:meth:`release`, with the flag's fields taken now and the message built
        later (:meth:`flag_of`): the service raises the interrupt in between, so
        building the flag is not on the batch -> interrupt path, and the flag still
        describes the block as it was released."""
        with self.block_lock:
            self.block.release()
        return self.flag_state("empty")

    def flag_state(self, state: BlockState) -> FlagState:
        """The fields of the next flag (numbered now)."""
        fields = FlagState(
            self.flag_seq, self.last_sim_time, state, self.block.next_seq, self.identifier.fft_width, self.batch_size, self.emulated_latency_s, self.config_seq
        )
        self.flag_seq += 1
        return fields

    @staticmethod
    def flag_of(fields: FlagState) -> BlockFlag:
        return BlockFlag(
            seq=fields.seq,
            sim_time_s=fields.sim_time_s,
            state=fields.state,
            next_batch_seq=fields.next_batch_seq,
            fft_width=fields.fft_width,
            batch_size=fields.batch_size,
            emulated_latency_s=fields.emulated_latency_s,
            config_seq=fields.config_seq,
        )

    def flag(self, state: BlockState) -> BlockFlag:
        return self.flag_of(self.flag_state(state))

    # -- configuration and downloads -----------------------------------------------------
    def apply_config(self, change: ConfigChange) -> None:
        """Run-time configuration; ``reset`` starts a new CPU run (sequence
        numbers from 0, history restarted, averages kept). A value the board
        cannot take raises ValueError and changes nothing."""
        if change.emulated_latency_s is not None and not change.emulated_latency_s <= MAX_EMULATED_LATENCY_S:
            raise ValueError(f"emulated_latency_s {change.emulated_latency_s} s exceeds {MAX_EMULATED_LATENCY_S:g} s")
        if change.reset:
            with self.block_lock:
                self.block.restart()
        with self.tf_lock:
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
        self.config_seq = change.seq

    def config_ack(self, change: ConfigChange, refused: str = "") -> ConfigAck:
        """The answer to ``change`` (on ``dsp/config_ack``): applied, or refused
        with the reason, and the configuration the board runs with now."""
        return ConfigAck.answering(change, not refused, refused, self.identifier.fft_width, self.batch_size, self.identifier.cfg.alpha, self.emulated_latency_s)

    def snapshot(self) -> TfSnapshot:
        """The current transfer-function estimates (magnitude and phase)."""
        with self.tf_lock:
            tf = self.identifier.transfer_functions()
            estimates: dict[TfName, TransferFunction] = {}
            for name in TF_NAMES:
                h = np.nan_to_num(np.asarray(getattr(tf, name)), nan=0.0, posinf=0.0, neginf=0.0)
                estimates[name] = TransferFunction(magnitude=np.abs(h), phase_rad=np.angle(h))
            snap = TfSnapshot(
                seq=self.tf_seq,
                sim_time_s=self.last_sim_time,
                batch_seq=self.last_batch_seq,
                freqs_hz=np.array(tf.freqs_hz, dtype=np.float64),  # copies: the snapshot outlives the lock
                valid=np.array(tf.valid, dtype=np.bool_),
                estimates=estimates,
            )
            self.tf_seq += 1
            return snap
