"""The frame-by-frame bus equals :func:`simulate` on the same frames, without errors and with injected ones."""

from __future__ import annotations

from typing import Any

from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire.arbitration import ErrorInjection, QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.error_state import ErrorState
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


injection_st = st.builds(
    ErrorInjection,
    arbitration_id=st.one_of(st.none(), st.sampled_from((0x080, 0x181, 0x201, 0x7FF))),
    node=st.one_of(st.none(), st.sampled_from(NODES)),
    start_ns=st.integers(0, 1_000_000),
    end_ns=st.one_of(st.none(), st.integers(1_000_000, 3_000_000)),
    every=st.integers(1, 3),
    probability=st.sampled_from((1.0, 0.5)),
    seed=st.integers(0, 9),
    count=st.integers(1, 80),
    echo_bits=st.integers(0, 6),
    first_attempts=st.one_of(st.none(), st.integers(1, 40)),
)
error_frames_st = st.lists(
    st.tuples(st.sampled_from(NODES), st.integers(0, 2_000_000), st.sampled_from((0x080, 0x181, 0x201, 0x7FF, 0x123)), st.binary(max_size=8), st.just(False)),
    min_size=1,
    max_size=30,
)


def _run_online(frames: list[QueuedFrame], bitrate: int, errors: list[ErrorInjection], *, lazy: bool) -> tuple[OnlineBus, list[Any], dict[int, int]]:
    order = sorted(range(len(frames)), key=lambda i: (frames[i].queued_ns, i))
    bus = OnlineBus(bitrate)
    for n in (*NODES, "sink"):
        bus.add_node(n)
    bus.inject(*errors)
    index_of: dict[int, int] = {}
    sent = []
    k = 0
    while k < len(order) or bus.pending:
        while k < len(order):
            start = bus.next_start()
            if lazy and start is not None and frames[order[k]].queued_ns > start:
                break
            i = order[k]
            index_of[bus.submit(frames[i].node, frames[i].queued_ns, frames[i].frame, tag=i)] = i
            k += 1
        sent.append(bus.commit())
    return bus, sent, index_of


@settings(max_examples=150, deadline=None)
@given(error_frames_st, st.sampled_from((125_000, 1_000_000)), st.lists(injection_st, min_size=1, max_size=3), st.booleans())
def test_errors_equal_simulate(raw: list[tuple[str, int, int, bytes, bool]], bitrate: int, errors: list[ErrorInjection], lazy: bool) -> None:
    """With injected errors: the same attempts (error frames, retransmissions, losers), transmissions,
    error-frame count and every node's state timeline as :func:`simulate` on the same frames and injections."""
    frames = _queued(raw)
    run = simulate(frames, bitrate, nodes=[*NODES, "sink"], errors=errors)
    assert not run.unsent
    bus, sent, index_of = _run_online(frames, bitrate, errors, lazy=lazy)
    attempts = [s.attempt for s in sent]
    assert all(a is not None for a in attempts)
    got = [
        (index_of[a.index], a.node, a.start_ns, a.end_ns, a.ok, a.bits, tuple(index_of[x] for x in a.losers), a.ack_error) for a in attempts if a is not None
    ]
    want = [(a.index, a.node, a.start_ns, a.end_ns, a.ok, a.bits, a.losers, a.ack_error) for a in run.attempts]
    assert got == want
    txs = [(index_of[t.index], t.start_ns, t.last_bit_ns, t.end_ns, t.attempts) for s in sent if (t := s.transmission) is not None]
    assert txs == [(t.index, t.start_ns, t.last_bit_ns, t.end_ns, t.attempts) for t in run.transmissions]
    assert bus.error_frames == sum(not a.ok for a in run.attempts)
    for name, node in bus.nodes.items():
        assert node.changes == [c for c in run.state_changes if c.node == name]


def test_bus_off_and_recovery_equal_simulate() -> None:
    """A node driven bus off by 32 errors on its frame, then its recovery after 128 x 11 recessive bits: as :func:`simulate`."""
    frames = [QueuedFrame("a", 0, frame_bits(0x181, bytes(8))), QueuedFrame("b", 10_000_000, frame_bits(0x201, b"\x01"))]
    errors = [ErrorInjection(arbitration_id=0x181, count=32)]
    run = simulate(frames, 1_000_000, nodes=[*NODES, "sink"], errors=errors)
    bus, sent, _ = _run_online(frames, 1_000_000, errors, lazy=True)
    states = [c.state for c in bus.nodes["a"].changes]
    assert ErrorState.BUS_OFF in states and states[-1] is ErrorState.ACTIVE
    assert bus.nodes["a"].changes == [c for c in run.state_changes if c.node == "a"]
    off = next(c for c in bus.nodes["a"].changes if c.state is ErrorState.BUS_OFF)
    back = next(c for c in bus.nodes["a"].changes if c.time_ns > off.time_ns and c.state is ErrorState.ACTIVE)
    last_error = [s.attempt for s in sent if s.attempt is not None and not s.attempt.ok][-1]
    assert back.time_ns == last_error.end_ns + 127 * 11 * 1000  # its delimiter and intermission are the first 11 bits
