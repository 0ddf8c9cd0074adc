"""The CPU side of the CPU-DSP handshake (thesis §3.2.3, Fig. 3.5), as a
pure state machine: the service feeds it samples, block flags and
interrupts, and asks it for the next batch to send.

Batching and back-pressure
    Every control tick adds one sample (the two D/A commands as inputs, the
    two link deflections as outputs) to a pending FIFO. When the DSP has
    flagged its block empty and at least ``batch_size`` samples are pending,
    *all* pending samples up to ``max_pending`` go out as one batch: while
    the DSP is busy, samples wait for the next batch instead of being lost.
    The FIFO is bounded by ``max_pending`` (default: the FFT width N, since
    the DSP's rolling history keeps only the last N samples anyway). Past
    that bound the oldest samples are dropped, counted, and the next batch
    says how many (``dropped_before``), so the DSP restarts its history
    rather than splice across the gap.

Bookkeeping
    The link also keeps what the service needs to match answers to
    batches: per batch in flight the wall time and the Unix time it went
    out (the batch path's stamps), when its interrupt arrived, the
    interrupts held until their due tick, the last batch's payload (resent
    while its interrupt is awaited in lockstep), and per batch answered or
    lost whether it missed its deadline (the longest run of misses). Each
    per-batch table keeps at most ``KEEP_BATCHES`` entries, so answers that
    never come cannot accumulate.

Timing
    Each batch's interrupt is due ``deadline_s`` after the batch was sent
    (default: the batch period, the thesis's deadline). In lockstep the
    answer is due at a defined simulated time (the DSP's emulated latency,
    announced in its flag) and the service waits for it at that tick.
"""

from __future__ import annotations

import math
from array import array
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from protocol.batch_codec import SampleBatch
from protocol.messages import BlockFlag, Interrupt
from service_kit.counters import Counters

LOST_AFTER_DEADLINES = 10
"""An interrupt this many deadlines late is taken as lost."""
KEEP_BATCHES = 64
"""Per-batch tables (sent stamps, arrivals, dropped arrivals) keep at most this many batches."""


def _bound(table: dict[int, object]) -> None:
    """Drop the oldest entries past ``KEEP_BATCHES`` (batches never answered must not accumulate)."""
    while len(table) > KEEP_BATCHES:
        del table[next(iter(table))]


@dataclass
class LinkCounters(Counters):
    samples_added: int = 0
    """samples (one per control tick) queued for the DSP"""
    samples_sent: int = 0
    """samples sent in batches"""
    samples_dropped: int = 0
    """samples that never reached the DSP: ticks skipped by a late loop, a full queue, a batch lost on the link"""
    batches_sent: int = 0
    """sample batches sent to the DSP"""
    interrupts: int = 0
    """interrupts that answered the batch in flight"""
    interrupts_unexpected: int = 0
    """interrupts for no batch in flight or another one (ignored)"""
    deadline_misses: int = 0
    """batches whose interrupt was not in by their deadline (once per batch)"""
    interrupts_lost: int = 0
    """batches declared unanswered (a timeout, or several deadlines past) so batching resumes"""
    flags_stale: int = 0
    """empty flags expecting neither the next batch nor the one before (ignored)"""
    flags_late: int = 0
    """empty flags overtaken by a later batch or interrupt (ignored)"""
    resyncs: int = 0
    """times the controller took the DSP's expected batch number (a restart on either side, a lost batch)"""


@dataclass(frozen=True)
class SentBatch:
    seq: int
    tick: int
    """Control tick at which it was sent."""
    sim_time_s: float
    due_tick: int
    """Lockstep: the tick at which its interrupt is applied."""
    deadline_tick: int
    """The tick after which a missing interrupt is a deadline miss."""


@dataclass
class DspLink:
    """Batches out, flags and interrupts in."""

    sample_rate_hz: float
    batch_size: int = 20
    max_pending_override: int | None = None
    """Bound of the pending FIFO; default: the DSP's FFT width N (it keeps N samples, more are moot)."""
    dsp_fft_width: int = 2048
    deadline_s: float | None = None
    counters: LinkCounters = field(default_factory=LinkCounters)
    block_empty: bool = False
    dsp_latency_s: float = 0.0
    next_seq: int = 0
    in_flight: SentBatch | None = None
    last_answered: int | None = None
    """The batch whose interrupt came last (a flag still expecting it is older than that interrupt)."""
    _pending_ticks: deque[int] = field(default_factory=deque)
    _pending: deque[tuple[float, ...]] = field(default_factory=deque)
    _dropped_since_last: int = 0
    _last_tick: int | None = None
    missed_current: bool = False
    held: list[Interrupt] = field(default_factory=list)
    """Interrupts taken in and not applied yet (lockstep: until their due tick)."""
    irq_arrival: dict[int, float] = field(default_factory=dict)
    """Per batch: when its interrupt arrived (the scheduler's clock)."""
    sent_wall: dict[int, float] = field(default_factory=dict)
    """Per batch in flight: when it went out (the scheduler's clock)."""
    sent_unix: dict[int, tuple[float, int]] = field(default_factory=dict)
    """Per batch in flight: Unix time sent (the batch path's first stamp) and its sample count."""
    dropped_arrived: set[int] = field(default_factory=set)
    """Batches whose interrupt came and a link fault dropped (lockstep waits for it)."""
    last_payload: bytes | None = None
    """The encoded batch last sent (resent while its interrupt is awaited); None: not to be resent."""
    acked: bool = False
    """The DSP flagged its block full since the last batch went out (it has the batch)."""
    batch_missed: array[int] = field(default_factory=lambda: array("b"))
    """Per batch answered or lost, in order: 1 if it missed its deadline (late or lost), else 0."""
    miss_run_max: int = 0
    """The longest run of consecutive batches that missed their deadline."""
    _miss_run: int = 0

    @property
    def sample_period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    @property
    def deadline(self) -> float:
        """The interrupt deadline after sending a batch (default: the batch period)."""
        return self.deadline_s if self.deadline_s is not None else self.batch_size * self.sample_period_s

    @property
    def max_pending(self) -> int:
        return self.max_pending_override or max(self.batch_size, self.dsp_fft_width)

    @property
    def pending(self) -> int:
        return len(self._pending)

    def add_sample(self, tick: int, commands: np.ndarray, deflections: np.ndarray) -> None:
        """Queue one tick's sample: inputs = D/A commands, outputs = deflections."""
        last = self._last_tick
        pending = self._pending
        if last is not None and tick != last + 1:
            if tick <= last:
                raise ValueError(f"ticks must increase: {last} then {tick}")
            # Sample instants were skipped (a late real-time loop): what waits is
            # cut off by the gap, so it goes too, and the next batch says so.
            lost = len(pending) + (tick - last - 1)
            pending.clear()
            self._pending_ticks.clear()
            self.counters.samples_dropped += lost
            self._dropped_since_last += lost
        self._last_tick = tick
        self._pending_ticks.append(tick)
        pending.append((*commands, *deflections))  # float64 values: take_batch reads them with np.array(dtype=float)
        self.counters.samples_added += 1
        if len(pending) <= self.batch_size and self.max_pending_override is None:
            return  # within the default bound max(batch_size, N): no property asked on most ticks
        while len(pending) > self.max_pending:
            self._pending.popleft()
            self._pending_ticks.popleft()
            self.counters.samples_dropped += 1
            self._dropped_since_last += 1

    def on_flag(self, flag: BlockFlag) -> None:
        """A block flag from the DSP. With no batch in flight the DSP's
        expected sequence number wins (a restart on either side, a lost
        batch); with one in flight, a flag that does not expect our next
        batch is late (zenoh does not order it with the interrupt) or stale,
        and counted."""
        self.dsp_latency_s = flag.emulated_latency_s
        if flag.state != "empty":
            self.block_empty = False
            return
        self.dsp_fft_width = flag.fft_width
        self._on_empty(flag.next_batch_seq)

    def on_released(self, interrupt: Interrupt) -> None:
        """An interrupt the controller does not take (a link fault dropped it
        after it came) still says that the board released its block, empty and
        expecting ``batch_seq + 1``: taken as that empty flag (as the flag
        older boards sent after every interrupt), never as the interrupt."""
        self._on_empty(interrupt.batch_seq + 1)

    def _on_empty(self, next_batch_seq: int) -> None:
        if next_batch_seq == self.next_seq:
            self.block_empty = True  # the batch in flight (if any) stays so until its interrupt arrives
        elif next_batch_seq == self.last_answered:
            # The board said it expects a batch whose interrupt is already in: the
            # flag left before that interrupt (an idle board's re-announce, on
            # another publisher, overtaken by it). Following it would send the
            # next samples under the answered number again: the board would take
            # them for a resend, answer with the old interrupt and restart its
            # history at the next batch (seen once in a loaded lockstep run).
            self.counters.flags_late += 1
        elif self.in_flight is None:
            # Nothing in flight and the DSP expects another number: it (or we)
            # restarted, or a batch was lost. Follow the DSP.
            self.counters.resyncs += 1
            self.next_seq = next_batch_seq
            self.block_empty = True
        elif next_batch_seq == self.next_seq - 1:
            self.counters.flags_late += 1  # overtaken by our next batch
        else:
            self.counters.flags_stale += 1

    def ready(self) -> bool:
        """A batch may go: the block is empty, the last batch's interrupt is in
        (the CPU reads the parameters immediately before sending new data, and
        zenoh does not order the flag and the interrupt), and enough samples wait."""
        return self.block_empty and self.in_flight is None and len(self._pending) >= self.batch_size

    def take_batch(self, tick: int, sim_time_s: float) -> tuple[SentBatch, SampleBatch] | None:
        """If the block is empty and a batch is ready, build it and mark the
        block full. Returns ``(sent, batch)`` or ``None``."""
        if not self.ready():
            return None
        data = np.array(self._pending, dtype=float).T
        first_tick = self._pending_ticks[0]
        self._pending.clear()
        self._pending_ticks.clear()
        batch = SampleBatch(
            seq=self.next_seq,
            first_tick=first_tick,
            sample_rate_hz=self.sample_rate_hz,
            sim_time_s=first_tick * self.sample_period_s,
            wall_time_s=0.0,
            inputs=data[:2],
            outputs=data[2:],
            dropped_before=self._dropped_since_last,
        )
        self._dropped_since_last = 0
        latency_ticks = math.ceil(round(self.dsp_latency_s * self.sample_rate_hz, 9))
        sent = SentBatch(
            seq=self.next_seq,
            tick=tick,
            sim_time_s=sim_time_s,
            due_tick=tick + latency_ticks,
            deadline_tick=tick + max(1, math.ceil(round(self.deadline * self.sample_rate_hz, 9))),
        )
        self.in_flight = sent
        self.missed_current = False
        self.next_seq += 1
        self.block_empty = False
        self.counters.batches_sent += 1
        self.counters.samples_sent += batch.n_samples
        return sent, batch

    def on_interrupt(self, interrupt: Interrupt) -> SentBatch | None:
        """Match an interrupt to the batch in flight; returns that batch. The
        interrupt is also the block's empty flag (the board sends no separate
        flag after it): the block is empty and the next batch may go."""
        sent = self.in_flight
        if sent is None or interrupt.batch_seq != sent.seq:
            self.counters.interrupts_unexpected += 1
            return None
        self.in_flight = None
        self.block_empty = True  # the DSP releases the block before it raises the interrupt (Fig. 3.5 step 4)
        self.counters.interrupts += 1
        self.last_answered = sent.seq
        return sent

    def note_lost_samples(self, n: int) -> None:
        """``n`` samples never reached the DSP (a batch lost on the link): the
        next batch says so, and the DSP restarts its history."""
        self.counters.samples_dropped += n
        self._dropped_since_last += n

    def declare_lost(self) -> None:
        """The interrupt of the batch in flight will not come (a timeout)."""
        if self.in_flight is not None:
            self.in_flight = None
            self.counters.interrupts_lost += 1

    def check_deadline(self, tick: int) -> bool:
        """True once per batch when its interrupt is overdue at ``tick``.

        An interrupt still missing ``LOST_AFTER_DEADLINES`` deadlines after
        the batch is declared lost (counted) so batching can resume."""
        sent = self.in_flight
        if sent is None:
            return False
        if tick > sent.tick + LOST_AFTER_DEADLINES * (sent.deadline_tick - sent.tick):
            self.in_flight = None
            self.counters.interrupts_lost += 1
            return False
        if self.missed_current or tick <= sent.deadline_tick:
            return False
        self.missed_current = True
        self.counters.deadline_misses += 1
        return True

    def note_batch(self, missed: bool) -> None:
        """A batch was answered (``missed``: past its deadline) or lost (missed)."""
        self.batch_missed.append(1 if missed else 0)
        self._miss_run = self._miss_run + 1 if missed else 0
        self.miss_run_max = max(self.miss_run_max, self._miss_run)

    def note_sent(self, seq: int, wall: float, unix: float, n_samples: int, payload: bytes) -> None:
        """Batch ``seq`` goes out now: its stamps and payload kept until its interrupt comes."""
        self.sent_wall[seq] = wall
        self.sent_unix[seq] = (unix, n_samples)
        _bound(self.sent_wall)  # type: ignore[arg-type]
        _bound(self.sent_unix)  # type: ignore[arg-type]
        self.last_payload = payload
        self.acked = False

    def note_arrival(self, seq: int, arrival: float) -> None:
        """The interrupt of batch ``seq`` arrived at ``arrival``."""
        self.irq_arrival[seq] = arrival
        _bound(self.irq_arrival)  # type: ignore[arg-type]

    def note_dropped_arrival(self, seq: int) -> None:
        """The interrupt of batch ``seq`` came and a link fault dropped it."""
        self.dropped_arrived.add(seq)
        if len(self.dropped_arrived) > KEEP_BATCHES:  # one that came after its wait timed out
            self.dropped_arrived.discard(min(self.dropped_arrived))
