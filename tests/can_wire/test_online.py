"""The frame-by-frame bus equals :func:`simulate` on the same frames (no errors)."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire.arbitration import QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.online import OnlineBus

NODES = ("a", "b", "c")

frames_st = st.lists(
    st.tuples(
        st.sampled_from(NODES),
        st.integers(0, 2_000_000),
        st.integers(0, 0x7FF),
        st.binary(max_size=8),
        st.booleans(),
    ),
    min_size=1,
    max_size=40,
)


def _queued(raw: list[tuple[str, int, int, bytes, bool]]) -> list[QueuedFrame]:
    out = []
    for node, t, ident, data, extended in raw:
        out.append(QueuedFrame(node, t, frame_bits(ident << 18 | ident if extended else ident, data, extended=extended)))
    return out


def _expected(frames: list[QueuedFrame], bitrate: int) -> list[tuple[int, int, int, int]]:
    run = simulate(frames, bitrate, nodes=["sink"])  # a receiver acknowledges: no ACK errors
    assert not run.unsent and all(a.ok for a in run.attempts)
    return [(t.index, t.start_ns, t.last_bit_ns, t.end_ns) for t in run.transmissions]


@settings(max_examples=150, deadline=None)
@given(frames_st, st.sampled_from((125_000, 500_000, 1_000_000)))
def test_all_frames_up_front_equal_simulate(raw: list[tuple[str, int, int, bytes, bool]], bitrate: int) -> None:
    frames = _queued(raw)
    order = sorted(range(len(frames)), key=lambda i: (frames[i].queued_ns, i))
    bus = OnlineBus(bitrate)
    index_of = {}
    for i in order:  # submission in simulate's arrival order; the index maps back
        index_of[bus.submit(frames[i].node, frames[i].queued_ns, frames[i].frame)] = i
    got = []
    while bus.pending:
        tx = bus.commit().transmission
        got.append((index_of[tx.index], tx.start_ns, tx.last_bit_ns, tx.end_ns))
    assert got == _expected(frames, bitrate)


@settings(max_examples=150, deadline=None)
@given(frames_st, st.sampled_from((250_000, 1_000_000)))
def test_frames_fed_as_they_come_equal_simulate(raw: list[tuple[str, int, int, bytes, bool]], bitrate: int) -> None:
    """Fed lazily, each frame only once the bus's next start reaches its queued time (the co-simulation's way)."""
    frames = _queued(raw)
    order = sorted(range(len(frames)), key=lambda i: (frames[i].queued_ns, i))
    bus = OnlineBus(bitrate)
    index_of: dict[int, int] = {}
    got = []
    k = 0
    while k < len(order) or bus.pending:
        while k < len(order):
            start = bus.next_start()
            if start is not None and frames[order[k]].queued_ns > start:
                break
            i = order[k]
            index_of[bus.submit(frames[i].node, frames[i].queued_ns, frames[i].frame, tag=i)] = i
            k += 1
        sent = bus.commit()
        assert sent.tag == index_of[sent.transmission.index]
        tx = sent.transmission
        got.append((index_of[tx.index], tx.start_ns, tx.last_bit_ns, tx.end_ns))
    assert got == _expected(frames, bitrate)


def test_lower_identifier_wins_and_waits_are_exact() -> None:
    """Two frames queued together at 1 Mbit/s: 0x080 (SYNC, no data) first, then 0x181 after its 47 bits."""
    bus = OnlineBus(1_000_000)
    tpdo = frame_bits(0x181, bytes(8))
    sync = frame_bits(0x080, b"")
    bus.submit("plant", 0, tpdo)
    bus.submit("controller", 0, sync)
    first, second = bus.commit().transmission, bus.commit().transmission
    assert (first.arbitration_id, first.start_ns) == (0x080, 0)
    assert first.end_ns == sync.n_bits * 1000
    assert (second.arbitration_id, second.start_ns, second.queuing_delay_ns) == (0x181, first.end_ns, first.end_ns)
