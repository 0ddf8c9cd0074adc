"""Decoding at the edge (service_kit.inbox): caps before decoding, bounded
queue, every drop counted, repeated bad input logged once per interval."""

from __future__ import annotations

import logging

import pytest

from protocol.errors import ProtocolError
from protocol.messages import BlockFlag, Interrupt, decode, encode
from service_kit.inbox import MAX_BYTES, REFUSED, Inbox, RateLimitedLog


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Payload:
    """Like zenoh.ZBytes: a length, and bytes only when asked (counted)."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.copies = 0

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        self.copies += 1
        return self.data


def _irq(seq: int) -> bytes:
    return encode(Interrupt(seq=seq, sim_time_s=0.0, batch_seq=seq, confidence=0.5, compute_time_s=0.01))


def test_oversize_payload_is_dropped_before_a_byte_is_copied() -> None:
    inbox = Inbox("t")
    huge = Payload(b"{" + b" " * (10 * 1024 * 1024) + b"}")
    decoded: list[bytes] = []
    assert not inbox.offer("interrupt", huge, lambda b: decoded.append(b), MAX_BYTES["interrupt"])
    assert huge.copies == 0 and decoded == []
    assert inbox.counters("interrupt").oversize == 1 and len(inbox) == 0
    assert inbox.as_dict() == {"in_interrupt_oversize": 1, "in_dropped": 1}


def test_flood_is_bounded_and_every_message_accounted_for() -> None:
    inbox = Inbox("t", capacity=32)
    for seq in range(5000):
        inbox.offer("interrupt", Payload(_irq(seq)), lambda b: decode(Interrupt, b), MAX_BYTES["interrupt"])
    c = inbox.counters("interrupt")
    assert len(inbox) == 32 and c.queued == 32 and c.dropped_full == 5000 - 32 and c.received == 5000
    items = inbox.drain()
    assert [i.message.batch_seq for i in items] == list(range(32))  # the oldest kept, in order
    assert all(isinstance(i.message, Interrupt) for i in items)


def test_undecodable_and_refused_are_counted_apart() -> None:
    inbox = Inbox("t")

    def flag(b: bytes) -> BlockFlag:
        return decode(BlockFlag, b)

    assert not inbox.offer("flag", b'{"seq": "x"}', flag, 1024)
    assert not inbox.offer("flag", b"\xff\x00", flag, 1024)
    assert not inbox.offer("interrupt", _irq(1), lambda b: REFUSED, 1 << 15)
    assert inbox.offer("interrupt", _irq(2), lambda b: None, 1 << 15)  # handled in the callback, nothing queued
    assert inbox.counters("flag").undecodable == 2 and inbox.counters("interrupt").refused == 1
    assert inbox.counters("interrupt").handled == 1 and len(inbox) == 0


def test_repeated_bad_input_logs_once_per_kind_per_interval(caplog: pytest.LogCaptureFixture) -> None:
    clock = FakeClock()
    inbox = Inbox("t", log_interval_s=10.0, clock=clock, logger=logging.getLogger("test.inbox"))
    with caplog.at_level(logging.WARNING, logger="test.inbox"):
        for _ in range(5000):
            inbox.offer("flag", b"junk", lambda b: decode(BlockFlag, b), 1024)
            inbox.offer("interrupt", b"x" * 100_000, lambda b: decode(Interrupt, b), 1024)
        assert len(caplog.records) == 2  # one per kind and reason
        clock.t = 10.5
        inbox.offer("flag", b"junk", lambda b: decode(BlockFlag, b), 1024)
    assert len(caplog.records) == 3
    assert "4999 more like it" in caplog.records[-1].getMessage()
    assert inbox.counters("flag").undecodable == 5001


def test_rate_limited_log_keys_are_independent() -> None:
    clock = FakeClock()
    log = RateLimitedLog(logging.getLogger("test.rl"), interval_s=1.0, clock=clock)
    assert log.warning("a", "x") and log.warning("b", "y") and not log.warning("a", "x")
    clock.t = 1.0
    assert log.warning("a", "x")


def test_decoder_errors_other_than_protocol_errors_propagate() -> None:
    # A bug in a decoder is not "bad input": it must not be counted away silently.
    inbox = Inbox("t")

    def broken(_: bytes) -> None:
        raise KeyError("bug")

    with pytest.raises(KeyError):
        inbox.offer("flag", b"{}", broken, 1024)
    assert issubclass(ProtocolError, ValueError)


def test_dsp_block_flood_logs_once(caplog: pytest.LogCaptureFixture) -> None:
    """5000 batches into a full block: all counted, one WARNING line (not 5000 lines, 682 KB)."""
    import numpy as np

    from dsp_service.board import BatchBlock
    from protocol.batch_codec import SampleBatch

    block = BatchBlock()
    batch = SampleBatch(seq=0, first_tick=0, sample_rate_hz=200.0, sim_time_s=0.0, wall_time_s=0.0, inputs=np.zeros((2, 30)), outputs=np.zeros((2, 30)))
    assert block.admit(batch).accepted
    with caplog.at_level(logging.WARNING, logger="dsp_service.board"):
        for seq in range(1, 5001):
            assert not block.admit(SampleBatch(**{**batch.__dict__, "seq": seq, "first_tick": 30 * seq})).accepted
    assert block.counters.block_full_violations == 5000
    assert len([r for r in caplog.records if r.name == "dsp_service.board"]) == 1
