"""The C40 board's batch handshake as a pure state machine (thesis §3.2.3,
Fig. 3.5): no zenoh, no clocks; the service feeds it batches and
publishes what it returns.

Policies (documented in the README):

* *Block full*: a batch that arrives while the previous one is still being
  processed is a protocol violation. It is rejected (counted, reported in
  health, logged) and never merged; the gap it leaves is then seen by the
  sequence check of the next accepted batch.
* *Sequence gaps*: a batch whose ``first_tick`` is later than the end of
  the previous one means samples are missing. The history is restarted
  (zeroed) so the FFT window never spans a discontinuity; the averaged
  spectra are kept, and the gap is counted with the number of samples lost.
* *Duplicates / reordering*: a batch with a sequence number already seen is
  dropped and counted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from protocol.batch_codec import SampleBatch
from protocol.messages import ConfigChange
from service_kit.counters import Counters
from service_kit.inbox import RateLimitedLog

log = logging.getLogger(__name__)
_log_once = RateLimitedLog(log)  # a flood of violations logs once per kind per 10 s (counted all the same)


@dataclass
class BoardCounters(Counters):
    batches_accepted: int = 0
    samples_accepted: int = 0
    block_full_violations: int = 0
    sequence_gaps: int = 0
    samples_missing: int = 0
    duplicates: int = 0
    decode_errors: int = 0
    rejected: int = 0
    config_changes: int = 0
    config_rejected: int = 0
    internal_errors: int = 0
    restarts: int = 0
    budget_misses: int = 0
    dropped_by_controller: int = 0
    interrupts_repeated: int = 0
    """A batch already answered came again (the CPU's resend after a lost interrupt): answered again."""


@dataclass(frozen=True)
class Admission:
    """What to do with an arriving batch."""

    accepted: bool
    restart_history: bool = False
    reason: str = ""


ACCEPTED = Admission(True)
"""The admission of a batch that follows the previous one (the usual case, built once)."""


@dataclass
class BatchBlock:
    """The batch memory block and the sequence bookkeeping around it."""

    counters: BoardCounters = field(default_factory=BoardCounters)
    full: bool = False
    next_seq: int = 0
    next_tick: int | None = None
    last_violation: str | None = None

    def admit(self, batch: SampleBatch) -> Admission:
        """Decide on an arriving batch; marks the block full when accepted."""
        if self.full:
            self.counters.block_full_violations += 1
            self.last_violation = f"batch {batch.seq} arrived while the block was full"
            _log_once.warning("violation", "protocol violation: %s; rejected", self.last_violation)
            return Admission(False, reason="block full")
        if batch.seq < self.next_seq:
            self.counters.duplicates += 1
            _log_once.warning("duplicate", "batch %d is a duplicate or out of order (expected %d); dropped", batch.seq, self.next_seq)
            return Admission(False, reason="duplicate")
        restart = False
        reason = ""
        if batch.seq > self.next_seq:
            self.counters.sequence_gaps += 1
            reason = f"batches {self.next_seq}..{batch.seq - 1} missing"
        if self.next_tick is not None and batch.first_tick != self.next_tick:
            missing = batch.first_tick - self.next_tick
            if missing > 0:
                self.counters.samples_missing += missing
                restart = True
                if not reason:
                    self.counters.sequence_gaps += 1
                reason = (reason + "; " if reason else "") + f"{missing} samples missing before tick {batch.first_tick}"
            else:
                self.counters.duplicates += 1
                _log_once.warning("overlap", "batch %d overlaps already received samples; dropped", batch.seq)
                return Admission(False, reason="overlap")
        if batch.dropped_before:
            self.counters.dropped_by_controller += batch.dropped_before
        if reason:
            self.last_violation = reason
            _log_once.warning("gap", "sequence gap: %s; history restarted", reason)
        self.full = True
        self.next_seq = batch.seq + 1
        self.next_tick = batch.first_tick + batch.n_samples
        self.counters.batches_accepted += 1
        self.counters.samples_accepted += batch.n_samples
        if not restart and not reason:
            return ACCEPTED
        return Admission(True, restart_history=restart, reason=reason)

    def release(self) -> None:
        """Flag the block empty again (Fig. 3.5 step 4)."""
        self.full = False

    def restart(self) -> None:
        """A new CPU run: sequence numbers and ticks start afresh."""
        self.full = False
        self.next_seq = 0
        self.next_tick = None
        self.counters.restarts += 1

    def note_config(self, change: ConfigChange) -> None:
        self.counters.config_changes += 1
