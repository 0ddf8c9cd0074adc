"""The CPU side of the handshake against a fake DSP: batches in order, no
sample lost while the DSP is busy, the bound past which samples drop,
deadline misses and lost interrupts."""

from __future__ import annotations

import numpy as np
import pytest

from controller.dsp_link import LOST_AFTER_DEADLINES, DspLink
from protocol.batch_codec import SampleBatch, decode_batch, encode_batch
from protocol.messages import BlockFlag, Interrupt


def flag(next_seq: int, latency: float = 0.0) -> BlockFlag:
    return BlockFlag(seq=0, sim_time_s=0.0, state="empty", next_batch_seq=next_seq, fft_width=2048, batch_size=20, emulated_latency_s=latency)


def irq(batch_seq: int) -> Interrupt:
    return Interrupt(seq=batch_seq, sim_time_s=0.0, batch_seq=batch_seq, confidence=0.5, compute_time_s=1e-4)


class FakeDsp:
    """Takes a batch, answers ``busy_ticks`` later with the interrupt (which is
    the block's empty flag); ``with_flags``: an older board, whose empty flag
    comes first."""

    def __init__(self, busy_ticks: int, with_flags: bool = True) -> None:
        self.busy_ticks = busy_ticks
        self.with_flags = with_flags
        self.received: list[SampleBatch] = []
        self.answer_at: int | None = None

    def receive(self, payload: bytes, tick: int) -> None:
        self.received.append(decode_batch(payload))
        self.answer_at = tick + self.busy_ticks

    def maybe_answer(self, tick: int, link: DspLink) -> None:
        if self.answer_at is not None and tick >= self.answer_at:
            last = self.received[-1].seq
            if self.with_flags:
                link.on_flag(flag(last + 1))
            link.on_interrupt(irq(last))
            self.answer_at = None


def drive(link: DspLink, dsp: FakeDsp, ticks: int) -> None:
    link.on_flag(flag(0))
    for tick in range(ticks):
        dsp.maybe_answer(tick, link)
        link.add_sample(tick, np.array([tick, -tick], float), np.array([0.5 * tick, 2.0 * tick]))
        taken = link.take_batch(tick, tick / 200.0)
        if taken is not None:
            dsp.receive(encode_batch(taken[1]), tick)
        link.check_deadline(tick)


@pytest.mark.parametrize("with_flags", [True, False])
def test_batches_in_order_and_every_sample_delivered_once(with_flags: bool) -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20)
    dsp = FakeDsp(busy_ticks=5, with_flags=with_flags)
    drive(link, dsp, 1000)
    seqs = [b.seq for b in dsp.received]
    assert seqs == list(range(len(seqs)))
    ticks = np.concatenate([b.inputs[0] for b in dsp.received])
    assert np.array_equal(ticks, np.arange(ticks.size))  # contiguous, no loss, no duplicate
    firsts = [b.first_tick for b in dsp.received]
    assert all(b.first_tick == int(b.inputs[0, 0]) for b in dsp.received)
    assert firsts == sorted(firsts)
    out = np.concatenate([b.outputs for b in dsp.received], axis=1)
    assert np.array_equal(out[1], 2.0 * ticks)
    assert link.counters.samples_dropped == 0 and link.counters.deadline_misses == 0


def test_a_busy_dsp_gets_larger_batches_and_nothing_is_lost() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20)
    dsp = FakeDsp(busy_ticks=50)  # 250 ms: longer than the 100 ms batch period
    drive(link, dsp, 2000)
    sizes = [b.n_samples for b in dsp.received]
    assert max(sizes) > 20  # samples waited for the next batch
    ticks = np.concatenate([b.inputs[0] for b in dsp.received])
    assert np.array_equal(ticks, np.arange(ticks.size))
    assert link.counters.samples_dropped == 0
    assert link.counters.deadline_misses == len(dsp.received) - (dsp.answer_at is None)  # every batch overran its deadline


def test_past_the_bound_the_oldest_samples_drop_and_the_batch_says_so() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20, max_pending_override=100)
    link.on_flag(flag(0))
    for tick in range(20):
        link.add_sample(tick, np.zeros(2), np.zeros(2))
    first = link.take_batch(19, 0.095)
    assert first is not None
    # the DSP never answers: samples pile up past the bound
    for tick in range(20, 400):
        link.add_sample(tick, np.array([tick, 0.0]), np.zeros(2))
    assert link.pending == 100
    assert link.counters.samples_dropped == 280
    link.on_interrupt(irq(0))
    link.on_flag(flag(1))
    sent, batch = link.take_batch(400, 2.0)  # type: ignore[misc]
    assert batch.dropped_before == 280 and batch.first_tick == 300 and batch.n_samples == 100


def test_missing_interrupt_counts_a_miss_then_is_declared_lost() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20)
    link.on_flag(flag(0))
    for tick in range(20):
        link.add_sample(tick, np.zeros(2), np.zeros(2))
    sent, _ = link.take_batch(19, 0.095)  # type: ignore[misc]
    assert not link.check_deadline(sent.deadline_tick)
    assert link.check_deadline(sent.deadline_tick + 1)
    assert not link.check_deadline(sent.deadline_tick + 2)  # one miss per batch
    assert link.counters.deadline_misses == 1
    link.check_deadline(sent.tick + LOST_AFTER_DEADLINES * 20 + 1)
    assert link.in_flight is None and link.counters.interrupts_lost == 1


def test_stale_flags_and_unexpected_interrupts_are_counted() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=1)
    link.on_flag(flag(0))
    link.add_sample(0, np.zeros(2), np.zeros(2))
    assert link.take_batch(0, 0.0) is not None  # batch 0 in flight
    link.on_flag(flag(7))
    assert not link.block_empty and link.counters.flags_stale == 1
    assert link.on_interrupt(irq(3)) is None and link.counters.interrupts_unexpected == 1


def test_an_interrupt_dropped_on_the_link_still_empties_the_block_it_released() -> None:
    """A link fault dropped batch 0's interrupt after it came: the link does
    not take it as the interrupt (batch 0 stays in flight until declared
    lost), but the board did release its block, expecting batch 1."""
    link = DspLink(sample_rate_hz=200.0, batch_size=1)
    link.on_flag(flag(0))
    link.add_sample(0, np.zeros(2), np.zeros(2))
    assert link.take_batch(0, 0.0) is not None
    assert not link.block_empty
    link.on_released(irq(0))
    assert link.block_empty and link.in_flight is not None and link.counters.interrupts == 0
    link.declare_lost()
    link.add_sample(1, np.zeros(2), np.zeros(2))
    taken = link.take_batch(1, 0.005)
    assert taken is not None and taken[0].seq == 1
    link.on_released(irq(0))  # a stale one: overtaken by batch 1, counted as late
    assert not link.block_empty and link.counters.flags_late == 1


def test_with_nothing_in_flight_the_dsp_sequence_wins() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=1)
    link.next_seq = 6  # e.g. our batch 5 was lost, or the DSP restarted
    link.on_flag(flag(5))
    assert link.block_empty and link.next_seq == 5 and link.counters.resyncs == 1


def test_a_flag_older_than_the_interrupt_it_was_overtaken_by_is_not_followed() -> None:
    """An idle board re-announces "empty, expecting k" on its flag publisher while
    batch k is on its way; the flag can arrive after batch k's interrupt. With
    nothing in flight then, following it would send the next samples as batch k
    again (the board takes them for a resend of k and restarts its history at
    k + 1): the link keeps its number and counts the flag late."""
    link = DspLink(sample_rate_hz=200.0, batch_size=1)
    link.on_flag(flag(0))
    for k in range(3):
        link.add_sample(k, np.zeros(2), np.zeros(2))
        sent, _ = link.take_batch(k, k / 200.0)  # type: ignore[misc]
        assert sent.seq == k
        assert link.on_interrupt(irq(k)) is sent
    link.on_flag(flag(2))  # the re-announce sent before batch 2 arrived
    assert link.next_seq == 3 and link.counters.resyncs == 0 and link.counters.flags_late == 1
    link.add_sample(3, np.zeros(2), np.zeros(2))
    sent, _ = link.take_batch(3, 3 / 200.0)  # type: ignore[misc]
    assert sent.seq == 3
    link.on_interrupt(irq(3))
    link.on_flag(flag(0))  # a board that restarted does expect another number: followed
    assert link.next_seq == 0 and link.counters.resyncs == 1


def test_lockstep_due_tick_follows_the_announced_latency() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20)
    link.on_flag(flag(0, latency=0.1))
    for tick in range(20):
        link.add_sample(tick, np.zeros(2), np.zeros(2))
    sent, _ = link.take_batch(19, 0.095)  # type: ignore[misc]
    assert sent.due_tick == 39 and sent.deadline_tick == 39


def test_skipped_ticks_cut_the_batch_and_the_next_one_reports_the_gap() -> None:
    link = DspLink(sample_rate_hz=200.0, batch_size=20)
    link.on_flag(flag(0))
    for tick in range(10):
        link.add_sample(tick, np.zeros(2), np.zeros(2))
    for tick in range(60, 80):  # ticks 10..59 never happened
        link.add_sample(tick, np.zeros(2), np.zeros(2))
    _, batch = link.take_batch(79, 0.4)  # type: ignore[misc]
    assert batch.first_tick == 60 and batch.n_samples == 20
    assert batch.dropped_before == 60 and link.counters.samples_dropped == 60
