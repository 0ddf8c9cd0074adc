"""The bus model against Davis et al.'s response-time analysis
(service_kit/can_wire/response_time.py, from the paper's equations) and the
arbitration rules of ISO 11898-1."""

from __future__ import annotations

from hypothesis import assume, given, settings
from hypothesis import strategies as st

from service_kit.can_wire.arbitration import QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.response_time import Message, response_times
from service_kit.can_wire.timing import bit_time_ns

PAYLOAD = bytes([0xA5] * 8)  # 112 bits for ids 0x101..0x103


def _periodic(ident: int, node: str, period_ns: int, horizon_ns: int, data: bytes = PAYLOAD, offset_ns: int = 0) -> list[QueuedFrame]:
    frame = frame_bits(ident, data)
    return [QueuedFrame(node, t, frame) for t in range(offset_ns, horizon_ns, period_ns)]


def test_davis_example_reaches_the_revised_bound() -> None:
    """Davis et al. 2007, section 3: three messages of one transmission time
    C with periods 2.5 C, 3.5 C and 3.5 C. Tindell's original analysis gave
    the lowest one 3 C; its second instance actually takes 3.5 C, which the
    revised analysis finds and the bus model reproduces."""
    bitrate = 125_000
    c = frame_bits(0x101, PAYLOAD).n_bits * bit_time_ns(bitrate)
    assert {frame_bits(i, PAYLOAD).n_bits for i in (0x101, 0x102, 0x103)} == {112}
    periods = {0x101: c * 5 // 2, 0x102: c * 7 // 2, 0x103: c * 7 // 2}
    expected = response_times([Message(i, c, t) for i, t in periods.items()], bit_time_ns(bitrate))
    assert expected == {0x101: 2 * c, 0x102: 3 * c, 0x103: 7 * c // 2}
    horizon = 14 * c
    frames = [q for i, t in periods.items() for q in _periodic(i, f"n{i:x}", t, horizon)]
    run = simulate(frames, bitrate)
    worst: dict[int, int] = {}
    for tx in run.transmissions:
        worst[tx.arbitration_id] = max(worst.get(tx.arbitration_id, 0), tx.response_ns)
        assert tx.response_ns <= expected[tx.arbitration_id]
    assert worst[0x103] == expected[0x103]
    assert not run.unsent and len(run.transmissions) == len(frames)


def test_highest_priority_blocked_by_one_lower_frame() -> None:
    """R = B + C for the highest-priority message: a longest lower-priority
    frame starts just before it is queued (1 ns here)."""
    bitrate = 500_000
    bit = bit_time_ns(bitrate)
    hi = frame_bits(0x010, bytes(2))
    lo = frame_bits(0x600, bytes([0xA5] * 8))
    analytic = response_times(
        [Message(0x010, hi.n_bits * bit, 1_000_000), Message(0x600, lo.n_bits * bit, 1_000_000)],
        bit,
    )
    run = simulate([QueuedFrame("lo", 0, lo), QueuedFrame("hi", 1, hi)], bitrate)
    r_hi = next(t.response_ns for t in run.transmissions if t.arbitration_id == 0x010)
    assert r_hi <= analytic[0x010]
    assert analytic[0x010] - r_hi == 1  # reached, less the 1 ns head start of the blocking frame


message_sets = st.lists(
    st.tuples(st.integers(0, 0x7EF), st.integers(0, 8), st.integers(300, 3000), st.integers(0, 3000)),
    min_size=2,
    max_size=6,
    unique_by=lambda m: m[0],
)


@settings(max_examples=60, deadline=None)
@given(message_sets, st.booleans())
def test_never_above_the_analysis(spec: list[tuple[int, int, int, int]], synchronous: bool) -> None:
    """Random message sets (periods in bit times), released together (the
    critical instant) or with random offsets: no instance takes longer than
    the revised analysis allows."""
    bitrate = 250_000
    bit = bit_time_ns(bitrate)
    frames_of = {i: frame_bits(i, bytes([(i * 37 + k) & 0xFF for k in range(n)])) for i, n, _, _ in spec}
    messages = [Message(i, frames_of[i].n_bits * bit, period * bit) for i, _, period, _ in spec]
    assume(sum(m.c_ns / m.t_ns for m in messages) < 0.95)
    analytic = response_times(messages, bit)
    horizon = 8 * max(m.t_ns for m in messages)
    queued = [
        q
        for (i, _, period, offset), m in zip(spec, messages)
        for q in _periodic(i, f"n{i:x}", m.t_ns, horizon, frames_of[i].data, 0 if synchronous else offset * bit)
    ]
    run = simulate(queued, bitrate)
    assert len(run.transmissions) == len(queued)
    for tx in run.transmissions:
        assert tx.response_ns <= analytic[tx.arbitration_id], (tx, analytic)


def test_arbitration_rules() -> None:
    """Queued together, the frames go out in bitwise-arbitration order:
    lower id first; data before remote of one id; standard before extended
    of the same base id; between extended frames the lower 29-bit id."""
    frames = [
        QueuedFrame("a", 0, frame_bits(0x123 << 18, b"", extended=True)),  # base id 0x123, extended
        QueuedFrame("b", 0, frame_bits(0x123, remote=True, dlc=0)),
        QueuedFrame("c", 0, frame_bits(0x123, b"\xff")),
        QueuedFrame("d", 0, frame_bits(0x124, b"")),
        QueuedFrame("e", 0, frame_bits(0x122 << 18 | 5, b"", extended=True)),
        QueuedFrame("f", 0, frame_bits(0x122 << 18 | 4, b"", extended=True)),
    ]
    run = simulate(frames, 1_000_000)
    assert [t.node for t in run.transmissions] == ["f", "e", "c", "b", "a", "d"]
    # back to back: each starts when the previous intermission ends
    for before, after in zip(run.transmissions, run.transmissions[1:]):
        assert after.start_ns == before.end_ns
    assert run.attempts[0].losers == (4, 2, 1, 0, 3)


def test_node_sends_its_own_highest_priority_first_and_idle_bus_starts_at_once() -> None:
    f1, f2 = frame_bits(0x300, b"\x01"), frame_bits(0x200, b"\x02")
    run = simulate([QueuedFrame("x", 0, f1), QueuedFrame("x", 10, f2), QueuedFrame("y", 1_000_000, f1)], 1_000_000)
    assert [(t.arbitration_id, t.start_ns) for t in run.transmissions] == [(0x300, 0), (0x200, f1.n_bits * 1000), (0x300, 1_000_000)]
    assert run.transmissions[1].queuing_delay_ns == f1.n_bits * 1000 - 10
    assert run.transmissions[0].last_bit_ns == (f1.n_bits - 3) * 1000
