"""The batch block's handshake bookkeeping (pure): admission, violations, gaps."""

from __future__ import annotations

import numpy as np

from dsp_service.board import BatchBlock
from protocol.batch_codec import SampleBatch


def _batch(seq: int, first_tick: int, n: int = 20, dropped: int = 0) -> SampleBatch:
    return SampleBatch(
        seq=seq,
        first_tick=first_tick,
        sample_rate_hz=200.0,
        sim_time_s=first_tick / 200.0,
        wall_time_s=0.0,
        inputs=np.zeros((2, n)),
        outputs=np.zeros((2, n)),
        dropped_before=dropped,
    )


def test_consecutive_batches_are_admitted_and_release_empties_the_block() -> None:
    block = BatchBlock()
    assert block.admit(_batch(0, 0)).accepted and block.full
    block.release()
    assert not block.full
    admission = block.admit(_batch(1, 20))
    assert admission.accepted and not admission.restart_history
    assert block.counters.batches_accepted == 2 and block.counters.samples_accepted == 40


def test_a_batch_while_full_is_a_violation_and_is_not_merged() -> None:
    block = BatchBlock()
    block.admit(_batch(0, 0))
    admission = block.admit(_batch(1, 20))
    assert not admission.accepted
    assert block.counters.block_full_violations == 1
    assert block.counters.batches_accepted == 1
    assert "full" in (block.last_violation or "")


def test_sequence_gap_restarts_history_and_counts_missing_samples() -> None:
    block = BatchBlock()
    block.admit(_batch(0, 0))
    block.release()
    admission = block.admit(_batch(3, 80))
    assert admission.accepted and admission.restart_history
    assert block.counters.sequence_gaps == 1
    assert block.counters.samples_missing == 60


def test_controller_side_drops_are_a_gap_in_ticks_even_with_consecutive_seq() -> None:
    block = BatchBlock()
    block.admit(_batch(0, 0))
    block.release()
    admission = block.admit(_batch(1, 50, dropped=30))
    assert admission.restart_history
    assert block.counters.samples_missing == 30 and block.counters.dropped_by_controller == 30


def test_duplicates_and_overlaps_are_dropped() -> None:
    block = BatchBlock()
    block.admit(_batch(0, 0))
    block.release()
    assert not block.admit(_batch(0, 0)).accepted
    assert not block.admit(_batch(1, 10)).accepted  # overlaps samples already received
    assert block.counters.duplicates == 2
    assert block.admit(_batch(1, 20)).accepted
