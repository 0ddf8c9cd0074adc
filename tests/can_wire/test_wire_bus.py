"""The ``ralfwire`` python-can interface: the same delivery times as the bus
model for the same inputs (manual clock), stock tools on it in real time
(python-can's Bus and Notifier, a canopen master driving the plant's
CANopen node), and its refusals."""

from __future__ import annotations

import queue
import threading
import time
import uuid
from collections.abc import Callable
from pathlib import Path

import can
import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from plant_emulator.canopen_node import CanopenNode, NodeConfig, run_node
from service_kit.can_wire.arbitration import QueuedFrame, simulate
from service_kit.can_wire.bits import frame_of_message
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus, wire_of
from tests.plant.support import EDS, FakeApp

BITRATE = 500_000


def _channel() -> str:
    return f"ralfwire-test-{uuid.uuid4().hex}"


frames_strategy = st.lists(
    st.tuples(st.sampled_from(["a", "b", "c"]), st.integers(0, 2_000_000), st.integers(0, 0x7EF), st.binary(max_size=8)),
    min_size=1,
    max_size=30,
)


@settings(max_examples=40, deadline=None)
@given(frames_strategy)
def test_same_times_as_the_bus_model(spec: list[tuple[str, int, int, bytes]]) -> None:
    spec = sorted(spec, key=lambda s: s[1])
    clock = ManualWireClock()
    channel = _channel()
    buses = {n: WireBus(channel=channel, bitrate=BITRATE, clock=clock, keep_log=True) for n in "abc"}
    listener = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    try:
        msgs = [can.Message(arbitration_id=i, data=d, is_extended_id=False) for _, _, i, d in spec]
        for (node, t, _, _), msg in zip(spec, msgs):
            clock.advance_to(t)
            buses[node].send(msg)
        while (t := clock.next_event_ns()) is not None:
            clock.advance_to(t)
        model = simulate([QueuedFrame(n, t, frame_of_message(m)) for (n, t, _, _), m in zip(spec, msgs)], BITRATE, nodes=["listener"])
        wire = wire_of(channel)
        assert wire is not None
        assert [(d.arbitration_id, d.queued_ns, d.start_ns, d.last_bit_ns) for d in wire.log] == [
            (tx.arbitration_id, tx.queued_ns, tx.start_ns, tx.last_bit_ns) for tx in model.transmissions
        ]
        received = [listener.recv(0) for _ in spec]
        assert [(m.arbitration_id, m.timestamp) for m in received if m] == [(tx.arbitration_id, tx.last_bit_ns / 1e9) for tx in model.transmissions]
        assert listener.recv(0) is None
    finally:
        for bus in [*buses.values(), listener]:
            bus.shutdown()
    assert wire_of(channel) is None


def test_stock_bus_in_real_time() -> None:
    """Frames sent by one node in a burst: whatever the host's pace, no frame
    went on the wire while a lower identifier queued by then waited, none
    overlapped, and each took its wire time."""
    channel = _channel()
    a = can.Bus(interface="ralfwire", channel=channel, bitrate=1_000_000, keep_log=True)
    b = can.Bus(interface="ralfwire", channel=channel, bitrate=1_000_000, receive_own_messages=True)
    try:
        ids = [0x700, 0x300, 0x100, 0x500, 0x080]
        for i in ids:
            a.send(can.Message(arbitration_id=i, data=bytes([i & 0xFF] * 8), is_extended_id=False))
        got = [b.recv(5.0) for _ in ids]
        assert all(m is not None for m in got)
        log = a.wire.log  # type: ignore[attr-defined]
        assert [m.arbitration_id for m in got if m] == [d.arbitration_id for d in log]
        for i, first in enumerate(log):
            for later in log[i + 1 :]:
                if later.queued_ns <= first.start_ns:
                    assert later.arbitration_id > first.arbitration_id
        for before, after in zip(log, log[1:]):
            assert after.start_ns >= before.end_ns
        for d, m in zip(log, got):
            assert m is not None and d.arbitration_id == m.arbitration_id
            assert d.last_bit_ns - d.start_ns == (frame_of_message(m).n_bits - 3) * 1000
        b.send(can.Message(arbitration_id=0x10, is_extended_id=False))
        echo = b.recv(5.0)
        assert echo is not None and echo.arbitration_id == 0x10  # receive_own_messages: after its wire time too
    finally:
        a.shutdown()
        b.shutdown()


def _wait(pred: Callable[[], bool], timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


def test_canopen_master_drives_the_plant_node_over_the_wire() -> None:
    channel = _channel()
    app = FakeApp(volts=(3.2, -1.1, 0.25, -9.5))
    node = CanopenNode(app, NodeConfig(watchdog_periods=0))
    node_bus = can.Bus(interface="ralfwire", channel=channel, bitrate=BITRATE, keep_log=True)
    network = canopen.Network()
    network.connect(interface="ralfwire", channel=channel, bitrate=BITRATE)
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(node_bus, node, stop), daemon=True)
    thread.start()
    try:
        remote = network.add_node(1, str(EDS))
        assert _wait(lambda: remote.nmt.state == "PRE-OPERATIONAL")
        assert remote.sdo[0x1000].raw == 0x000C0191
        remote.nmt.state = "OPERATIONAL"
        assert _wait(lambda: remote.nmt.state == "OPERATIONAL")
        remote.tpdo.read()
        got: queue.Queue[list[int]] = queue.Queue()
        remote.tpdo[1].add_callback(lambda m: got.put([v.raw for v in m]))
        network.sync.transmit(1)
        assert len(got.get(timeout=5.0)) == 4
        log = node_bus.wire.log  # type: ignore[attr-defined]
        ids = [d.arbitration_id for d in log]
        assert 0x080 in ids and 0x181 in ids[ids.index(0x080) :]
        sync, tpdo = log[ids.index(0x080)], log[len(ids) - 1 - ids[::-1].index(0x181)]
        assert tpdo.start_ns >= sync.end_ns  # the plant answers a SYNC it has received whole
    finally:
        stop.set()
        thread.join(10.0)
        network.disconnect()
        node_bus.shutdown()


def test_refusals() -> None:
    channel = _channel()
    bus = WireBus(channel=channel, bitrate=BITRATE)
    try:
        with pytest.raises(can.CanOperationError, match="FD"):
            bus.send(can.Message(arbitration_id=1, data=bytes(12), is_fd=True))
        with pytest.raises(can.CanInitializationError, match="bit/s"):
            WireBus(channel=channel, bitrate=250_000)
        with pytest.raises(can.CanInitializationError, match="nanoseconds"):
            WireBus(channel=_channel(), bitrate=300_000)
        with pytest.raises(ValueError, match="back"):
            clock = ManualWireClock(10)
            clock.advance_to(5)
    finally:
        bus.shutdown()


def test_pending_frames_of_a_closed_bus_are_dropped_and_counted() -> None:
    clock = ManualWireClock()
    channel = _channel()
    a = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    b = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    c = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    try:
        a.send(can.Message(arbitration_id=0x100, is_extended_id=False))  # on the wire at once
        b.send(can.Message(arbitration_id=0x200, is_extended_id=False))  # waits
        b.shutdown()
        while (t := clock.next_event_ns()) is not None:
            clock.advance_to(t)
        assert [m.arbitration_id for m in iter(lambda: c.recv(0), None)] == [0x100]
        assert a.wire.dropped == 1
    finally:
        a.shutdown()
        c.shutdown()


def test_logger_on_a_notifier_records_wire_time_stamps(tmp_path: Path) -> None:
    """python-can's Notifier and Logger on a ralfwire bus: the log file (CSV,
    whose timestamps python-can writes with every digit) holds each frame
    stamped at its last EOF bit, as the bus model places it."""
    clock = ManualWireClock()
    channel = _channel()
    sender = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    listener = WireBus(channel=channel, bitrate=BITRATE, clock=clock)
    path = tmp_path / "wire.csv"
    logger = can.Logger(str(path))
    seen: queue.Queue[can.Message] = queue.Queue()
    notifier = can.Notifier(listener, [logger, seen.put], timeout=0.05)
    msgs = [can.Message(arbitration_id=0x181 + k % 2, data=bytes([k] * 8), is_extended_id=False) for k in range(6)]
    try:
        for k, msg in enumerate(msgs):
            clock.advance_to(k * 50_000)
            sender.send(msg)
        while (t := clock.next_event_ns()) is not None:
            clock.advance_to(t)
        for _ in msgs:
            seen.get(timeout=10.0)
    finally:
        notifier.stop()  # stops the logger too
        sender.shutdown()
        listener.shutdown()
    model = simulate([QueuedFrame("s", k * 50_000, frame_of_message(m)) for k, m in enumerate(msgs)], BITRATE, nodes=["l"])
    logged = list(can.LogReader(str(path)))
    assert [m.arbitration_id for m in logged] == [tx.arbitration_id for tx in model.transmissions]
    for m, tx in zip(logged, model.transmissions):
        assert abs(round(m.timestamp * 1e9) - tx.last_bit_ns) <= 1  # nanoseconds through a float
