"""Error frames and fault confinement on ``ralfwire``: the same delivery
times, attempts and counter timelines as the bus model
(:func:`service_kit.can_wire.arbitration.simulate`) for the same injected
errors, and a bus-off -> recovery timeline worked out in bit times from the
rules (CAN 2.0 part B section 8 / ISO 11898-1)."""

from __future__ import annotations

import time
import uuid

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire.arbitration import ErrorInjection, QueuedFrame, simulate
from service_kit.can_wire.bits import frame_of_message
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus, wire_of

BITRATE = 500_000
BIT = 2000
NODES = ("a", "b", "c")


def _run_out(clock: ManualWireClock) -> None:
    while (t := clock.next_event_ns()) is not None:
        clock.advance_to(t)


injection_strategy = st.builds(
    ErrorInjection,
    arbitration_id=st.one_of(st.none(), st.sampled_from([0x080, 0x181, 0x201, 0x701])),
    node=st.one_of(st.none(), st.sampled_from(NODES)),
    start_ns=st.integers(0, 1_000_000),
    end_ns=st.one_of(st.none(), st.integers(1_000_000, 20_000_000)),
    every=st.integers(1, 3),
    probability=st.sampled_from([1.0, 0.5]),
    seed=st.integers(0, 10),
    count=st.integers(1, 40),
    bit=st.one_of(st.none(), st.integers(0, 40)),
    echo_bits=st.integers(0, 6),
    first_attempts=st.one_of(st.none(), st.integers(1, 4)),
)

frames_strategy = st.lists(
    st.tuples(st.sampled_from(NODES), st.integers(0, 2_000_000), st.sampled_from([0x080, 0x181, 0x201, 0x701]), st.binary(max_size=8)),
    min_size=1,
    max_size=20,
)


@settings(max_examples=60, deadline=None)
@given(frames_strategy, st.lists(injection_strategy, max_size=3))
def test_same_times_and_states_as_the_bus_model(spec: list[tuple[str, int, int, bytes]], errors: list[ErrorInjection]) -> None:
    spec = sorted(spec, key=lambda s: s[1])
    clock = ManualWireClock()
    channel = f"wire-errors-{uuid.uuid4().hex}"
    buses = {n: WireBus(channel=channel, bitrate=BITRATE, clock=clock, keep_log=True, node=n) for n in NODES}
    listener = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="listener")
    try:
        wire = wire_of(channel)
        assert wire is not None
        wire.inject_errors(*errors)
        msgs = [can.Message(arbitration_id=i, data=d, is_extended_id=False) for _, _, i, d in spec]
        refused = 0
        sent: list[QueuedFrame] = []
        for (node, t, _, _), msg in zip(spec, msgs):
            clock.advance_to(t)
            if buses[node].can_error_state is ErrorState.BUS_OFF:
                with pytest.raises(can.CanOperationError, match="bus off"):
                    buses[node].send(msg)
                refused += 1
                continue
            buses[node].send(msg)
            sent.append(QueuedFrame(node, t, frame_of_message(msg)))
        _run_out(clock)
        model = simulate(sent, BITRATE, nodes=[*NODES, "listener"], errors=errors)
        assert [(d.arbitration_id, d.queued_ns, d.start_ns, d.last_bit_ns, d.end_ns, d.attempts) for d in wire.log] == [
            (tx.arbitration_id, tx.queued_ns, tx.start_ns, tx.last_bit_ns, tx.end_ns, tx.attempts) for tx in model.transmissions
        ]
        assert wire.error_frames == sum(not a.ok for a in model.attempts)
        wire_changes = sorted((c for n in wire.nodes for c in n.changes), key=lambda c: (c.time_ns, c.node))
        assert wire_changes == sorted(model.state_changes, key=lambda c: (c.time_ns, c.node))
        for n in wire.nodes:
            assert [c.time_ns for c in n.changes] == sorted(c.time_ns for c in n.changes)  # status_at's premise
            fc = model.counters[n.name]
            assert (n.fc.tec, n.fc.rec, n.fc.state) == (fc.tec, fc.rec, fc.state)
        received = [m for _ in model.transmissions if (m := listener.recv(0)) is not None]
        assert [(m.arbitration_id, m.timestamp) for m in received] == [(tx.arbitration_id, tx.last_bit_ns / 1e9) for tx in model.transmissions]
    finally:
        for bus in [*buses.values(), listener]:
            bus.shutdown()


def test_bus_off_and_recovery_timeline_in_bit_times() -> None:
    """Node ``a``'s frame fails 32 times at its ACK delimiter; worked from the rules:

    - each attempt costs the bits up to and including the ACK delimiter, the
      6-bit flag, the 8-bit delimiter and the 3-bit intermission; TEC +8 at
      each flag (rule 3), the listener's REC +1 (rule 1);
    - the 16th error makes TEC 128: error passive (rule 9) from that flag on,
      and after each of its attempts ``a`` waits 8 bits more (suspend);
    - the 32nd makes TEC 256: bus off (rule 10); its own delimiter and
      intermission are the first 11 recessive bits, 127 x 11 idle bits more
      recover it (rule 12): error active, counters 0;
    - then the frame goes through (TEC stays 0) and the listener's REC, 32,
      goes down by 1 (rule 8)."""
    clock = ManualWireClock()
    channel = f"wire-errors-{uuid.uuid4().hex}"
    a = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="a", keep_log=True, can_errors=[ErrorInjection(arbitration_id=0x181, count=32)])
    listener = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="listener")
    try:
        msg = can.Message(arbitration_id=0x181, data=bytes(range(8)), is_extended_id=False)
        frame = frame_of_message(msg)
        a.send(msg)
        to_flag = frame.ack_delimiter_index + 1
        attempt = to_flag + 6 + 8 + 3
        starts = []
        t = 0
        for k in range(1, 33):
            starts.append(t)
            t += attempt * BIT
            if 16 <= k < 32:
                t += 8 * BIT  # suspend transmission
        passive_at = starts[15] + to_flag * BIT
        bus_off_at = starts[31] + to_flag * BIT
        bus_off_end = starts[31] + attempt * BIT
        recovered_at = bus_off_end + 127 * 11 * BIT
        clock.advance_to(passive_at - 1)
        assert a.error_status().state is ErrorState.ACTIVE and a.error_status().tec == 120
        clock.advance_to(passive_at)
        assert (a.error_status().state, a.error_status().tec) == (ErrorState.PASSIVE, 128)
        assert listener.error_status().rec == 16
        clock.advance_to(bus_off_at)
        assert (a.can_error_state, a.error_status().tec) == (ErrorState.BUS_OFF, 256)
        with pytest.raises(can.CanOperationError, match="bus off"):
            a.send(msg)
        clock.advance_to(recovered_at - 1)
        assert a.can_error_state is ErrorState.BUS_OFF
        clock.advance_to(recovered_at)
        assert a.error_status() == type(a.error_status())(ErrorState.ACTIVE, 0, 0)
        _run_out(clock)
        wire = a.wire
        assert [(d.start_ns, d.attempts) for d in wire.log] == [(recovered_at, 33)]
        assert wire.error_frames == 32
        got = listener.recv(0)
        assert got is not None and got.timestamp == (recovered_at + (frame.n_bits - 3) * BIT) / 1e9
        assert (a.node.fc.tec, listener.node.fc.rec) == (0, 31)
        states = [(c.time_ns, c.state) for c in a.node.changes if c.state is not ErrorState.ACTIVE or c.time_ns == recovered_at]
        assert states[0] == (passive_at, ErrorState.PASSIVE)
        assert (bus_off_at, ErrorState.BUS_OFF) in states and states[-1] == (recovered_at, ErrorState.ACTIVE)
        model = simulate([QueuedFrame("a", 0, frame)], BITRATE, nodes=["listener"], errors=[ErrorInjection(arbitration_id=0x181, count=32)])
        assert a.node.changes + listener.node.changes == [c for c in model.state_changes if c.node == "a"] + [
            c for c in model.state_changes if c.node == "listener"
        ]
    finally:
        a.shutdown()
        listener.shutdown()


def test_errors_off_by_default_and_names_unique() -> None:
    clock = ManualWireClock()
    channel = f"wire-errors-{uuid.uuid4().hex}"
    lone = WireBus(channel=channel, bitrate=BITRATE, clock=clock, keep_log=True)
    try:
        lone.send(can.Message(arbitration_id=0x100, is_extended_id=False))
        _run_out(clock)
        assert lone.wire.error_frames == 0 and len(lone.wire.log) == 1  # no ACK error without injection
        assert lone.node.changes == []
        with pytest.raises(can.CanInitializationError, match="already has a node"):
            WireBus(channel=channel, bitrate=BITRATE, clock=clock, node=lone.node.name)
        assert lone.wire._users == 1
    finally:
        lone.shutdown()


def test_each_nodes_timeline_is_in_time_order() -> None:
    """status_at reads a node's timeline from its newest end: it must be in time order,
    through passive, bus off and recovery of a sender and the receivers' counts."""
    clock = ManualWireClock()
    channel = f"wire-errors-{uuid.uuid4().hex}"
    buses = [WireBus(channel=channel, bitrate=BITRATE, clock=clock, node=n) for n in NODES]
    try:
        buses[0].wire.inject_errors(ErrorInjection(node="a", count=40), ErrorInjection(node="b", probability=0.5, seed=2, count=30))
        for k in range(30):
            clock.advance_to(k * 300_000)
            for bus, i in ((buses[0], 0x100), (buses[1], 0x200), (buses[2], 0x300)):
                if bus.can_error_state is not ErrorState.BUS_OFF:
                    bus.send(can.Message(arbitration_id=i + k, is_extended_id=False))
        _run_out(clock)
        states = {c.state for b in buses for c in b.node.changes}
        assert ErrorState.BUS_OFF in states and ErrorState.PASSIVE in states
        for b in buses:
            times = [c.time_ns for c in b.node.changes]
            assert times == sorted(times)
    finally:
        for bus in buses:
            bus.shutdown()


def test_each_frame_fails_its_first_attempts() -> None:
    """``first_attempts=2`` without a count: every frame of the identifier fails twice and
    goes through on its third attempt, on the wire as in the bus model; others are untouched."""
    clock = ManualWireClock()
    channel = f"wire-errors-{uuid.uuid4().hex}"
    errors = [ErrorInjection(arbitration_id=0x181, count=None, first_attempts=2)]
    a = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="a", keep_log=True, can_errors=errors)
    b = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="b")
    try:
        queued = []
        for k in range(5):
            clock.advance_to(k * 1_000_000)
            for i in (0x080, 0x181):
                msg = can.Message(arbitration_id=i, data=bytes([k]), is_extended_id=False)
                a.send(msg)
                queued.append(QueuedFrame("a", k * 1_000_000, frame_of_message(msg)))
        _run_out(clock)
        assert [(d.arbitration_id, d.attempts) for d in a.wire.log] == [(0x080, 1), (0x181, 3)] * 5
        model = simulate(queued, BITRATE, nodes=["b"], errors=errors)
        assert [(d.arbitration_id, d.start_ns, d.attempts) for d in a.wire.log] == [(t.arbitration_id, t.start_ns, t.attempts) for t in model.transmissions]
        assert a.wire.error_frames == 10
    finally:
        a.shutdown()
        b.shutdown()


def test_errors_on_the_real_time_clock() -> None:
    """The wire's own thread runs the same rules: three error frames, the fourth attempt
    delivered, the sender's TEC 3 x 8 - 1 and the receiver's REC 3 - 1."""
    channel = f"wire-errors-{uuid.uuid4().hex}"
    a = can.Bus(interface="ralfwire", channel=channel, bitrate=1_000_000, node="a", keep_log=True, can_errors=[ErrorInjection(arbitration_id=0x123, count=3)])
    b = can.Bus(interface="ralfwire", channel=channel, bitrate=1_000_000, node="b")
    try:
        a.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False))
        got = b.recv(5.0)
        assert got is not None and got.arbitration_id == 0x123
        assert [d.attempts for d in a.wire.log] == [4] and a.wire.error_frames == 3  # type: ignore[attr-defined]
        end = time.monotonic() + 5.0  # the counters' last change is at the end of the intermission
        while a.error_status().tec != 23 and time.monotonic() < end:  # type: ignore[attr-defined]
            time.sleep(0.001)
        assert (a.error_status().tec, b.error_status().rec) == (23, 2)  # type: ignore[attr-defined]
    finally:
        a.shutdown()
        b.shutdown()
