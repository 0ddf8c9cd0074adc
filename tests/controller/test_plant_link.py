"""The controller's CAN link under attack: junk datagrams on the udp_multicast
group, and a second master on the bus (raw python-can frames and a stock
``canopen`` master) sending SYNC, NMT, RPDO1 and SDO. Every case is bounded
in frames and time; udp_multicast tests run in the loopback-only namespace."""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import can
import canopen
import msgpack  # type: ignore[import-untyped]
import numpy as np
import numpy.typing as npt
import pytest

from controller.plant_link import PlantLink, echoing_bus
from plant_emulator.canopen_node import (
    CanopenNode,
    NodeConfig,
    node_can_filters,
    run_node,
)
from protocol import can_map
from protocol.can_map import EmcyCode, NmtCommand, NmtState
from service_kit.can_udp import FRAME_PREFIX

EDS = Path(__file__).resolve().parents[2] / "protocol" / "ralf_io.eds"
UDP_GROUP = "239.74.163.2"


class App:
    """A plant stand-in: constant A/D codes, valve voltages and watchdog events recorded."""

    def __init__(self) -> None:
        self.outputs: list[npt.NDArray[np.float64]] = []
        self.watchdog: list[bool] = []

    def on_sync(self, counter: int) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
        return np.array([100, -200, 300, -400], dtype=np.int64), np.zeros(4, dtype=bool)

    def on_outputs(self, volts: npt.NDArray[np.float64]) -> None:
        self.outputs.append(np.array(volts))

    def on_watchdog(self, tripped: bool) -> None:
        self.watchdog.append(tripped)


@contextmanager
def serving(bus: can.BusABC, node: CanopenNode) -> Iterator[None]:
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(bus, node, stop), name="node", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join(10.0)
        assert not thread.is_alive()


def frame(cob_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


def run_ticks(link: PlantLink, n: int, volts: tuple[float, float] = (0.5, -0.5)) -> int:
    """n controller ticks (SYNC, TPDO, RPDO); returns how many got their TPDO (waited for generously: the subject is what arrives, not how fast, and a loaded host may hold the node thread for a while)."""
    answered = 0
    for _ in range(n):
        link.send_sync()
        if link.wait_tpdo(5.0) is not None:
            answered += 1
        link.send_outputs(volts)
    return answered


# --- junk on the udp_multicast group (one datagram once killed the controller) ----------------


JUNK: dict[str, bytes] = {
    "not msgpack": b"\xc1\xc1\xc1 junk",
    "unknown key": msgpack.packb({"arbitration_id": 0x80, "data": b"\x01", "evil": 1}, use_bin_type=True),
    "not a dict": msgpack.packb([1, 2, 3]),
    "bad field": msgpack.packb({"arbitration_id": "SYNC", "data": 7}),
    "empty": b"",
    "a frame's first bytes, then junk": FRAME_PREFIX + b"\xc1 junk",
}


def _udp_buses(port: int, loop_free: bool = False) -> tuple[can.BusABC, can.BusABC]:
    interface = "ralf_udp_multicast" if loop_free else "udp_multicast"  # service_kit/can_udp.py, or python-can's own
    try:
        node_bus = can.Bus(interface=interface, channel=UDP_GROUP, port=port, can_filters=node_can_filters(1))
        link_bus = can.Bus(interface=interface, channel=UDP_GROUP, port=port)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    return node_bus, link_bus


@pytest.mark.timeout(60)
@pytest.mark.parametrize("loop_free", [False, True], ids=["python-can-bus", "loop-free-bus"])
def test_junk_datagrams_on_the_can_group_are_counted_and_dropped(caplog: pytest.LogCaptureFixture, loop_free: bool) -> None:
    """A raw UDP socket sends 6 kinds x 20 junk datagrams to the rig's group and
    port, interleaved with the controller's ticks: the link counts and drops
    each one (the rig's bus skips what does not begin as a python-can frame
    before decoding, ``junk_frames``), logs each kind that fails to decode
    once, and the run goes on (every TPDO arrives)."""
    port = 47001 + os.getpid() % 10000 // 2 * 2 + 2 * loop_free
    node_bus, link_bus = _udp_buses(port, loop_free)
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    attacker.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    node = CanopenNode(App(), NodeConfig(heartbeat_ms=20, watchdog_periods=0))
    link = PlantLink(link_bus, 1)
    caplog.set_level(logging.WARNING, logger="controller.plant_link")
    try:
        with serving(node_bus, node):
            assert echoing_bus(link_bus) != loop_free  # the loop-free bus never hands a sender its frames back
            try:
                link.start_node(timeout=2.0)
            except Exception as e:  # noqa: BLE001
                pytest.skip(f"no IPv4 multicast delivery on loopback: {e}")
            sent = 0
            answered = 0
            for _ in range(20):
                for payload in JUNK.values():
                    attacker.sendto(payload, (UDP_GROUP, port))
                    sent += 1
                answered += run_ticks(link, 1)
            deadline = time.monotonic() + 2.0
            while link.counters.rx_errors + link.counters.junk_frames < sent and time.monotonic() < deadline:
                link.poll(0.01)
                link.take_conflicts()  # copies the bus's junk count
            node.counters.junk_frames = int(getattr(node_bus, "junk_frames", 0))
    finally:
        attacker.close()
        node_bus.shutdown()
        link_bus.shutdown()
    assert answered == 20 and link.counters.tpdo_timeouts == 0
    # loopback delivers every datagram; each one counted: the rig's bus skips what is not a
    # python-can frame before decoding (junk_frames), the rest fails to decode (rx_errors)
    assert link.counters.rx_errors + link.counters.junk_frames == sent
    assert node.counters.rx_errors + node.counters.junk_frames == sent  # the plant survives them too
    if loop_free:  # only the one that begins as a frame does reaches the decoder
        assert link.counters.rx_errors == node.counters.rx_errors == sent // len(JUNK)
    dropped_logs = [r for r in caplog.records if "undecodable CAN input" in r.getMessage()]
    assert len(dropped_logs) <= len(JUNK) and (loop_free or dropped_logs)  # once per kind per interval, not once per datagram
    if loop_free:  # its own frames never come back: nothing to match
        assert link.counters.own_echoes == 0
    else:  # python-can's udp_multicast hands the link its own frames back: echoes, not a second master
        assert link.counters.own_echoes >= 20
    assert link.counters.foreign_sync == link.counters.foreign_rpdo == link.counters.foreign_nmt == 0
    assert link.take_conflicts() == []


# --- a second master on the bus ----------------------------------------------------------------


@contextmanager
def virtual_rig(cfg: NodeConfig | None = None) -> Iterator[tuple[PlantLink, CanopenNode, can.BusABC, str]]:
    channel = f"ralf-link-{uuid.uuid4().hex}"
    node_bus = can.Bus(interface="virtual", channel=channel)
    link_bus = can.Bus(interface="virtual", channel=channel)
    rogue = can.Bus(interface="virtual", channel=channel)
    node = CanopenNode(App(), cfg or NodeConfig(heartbeat_ms=20))
    try:
        with serving(node_bus, node):
            yield PlantLink(link_bus, 1), node, rogue, channel
    finally:
        for bus in (node_bus, link_bus, rogue):
            bus.shutdown()


@pytest.mark.timeout(30)
def test_foreign_sync_nmt_rpdo_and_sdo_are_detected_and_reported() -> None:
    with virtual_rig() as (link, _, rogue, _channel):
        link.start_node(timeout=2.0, sample_period_s=0.005)
        assert run_ticks(link, 5) == 5 and link.take_conflicts() == []
        rogue.send(frame(can_map.SYNC_COB_ID, bytes([77])))
        rogue.send(frame(can_map.RPDO1_BASE + 1, can_map.volts_to_output_frame([9.0, 9.0])[0]))
        rogue.send(frame(can_map.SDO_RX_BASE + 1, bytes([0x2B, 0x17, 0x10, 0, 0xE8, 0x03, 0, 0])))  # 0x1017 = 1000
        rogue.send(frame(can_map.NMT_COB_ID, can_map.encode_nmt(NmtCommand.ENTER_PRE_OPERATIONAL, 5)))  # another node: not judged
        rogue.send(frame(can_map.NMT_COB_ID, can_map.encode_nmt(NmtCommand.START, 0)))  # broadcast: ours too
        run_ticks(link, 3)
        conflicts = link.take_conflicts()
        c = link.counters
        assert (c.foreign_sync, c.foreign_rpdo, c.foreign_sdo, c.foreign_nmt) == (1, 1, 1, 1)
        assert {d.split(":")[0] for d in conflicts} >= {"foreign sync", "foreign rpdo", "foreign sdo", "foreign nmt"}
        assert link.take_conflicts() == []  # each event reported once
    assert c.own_echoes == 0  # virtual bus: no echoes, so each of those frames was someone else's


@pytest.mark.timeout(30)
def test_the_plants_conflict_emcys_reach_the_link_as_conflicts() -> None:
    """A rogue SYNC stream interleaved with ours: the link sees the foreign SYNCs,
    and the plant's SYNC_CONFLICT EMCY arrives as a conflict of its own."""
    with virtual_rig() as (link, node, rogue, _):
        link.start_node(timeout=2.0, sample_period_s=0.005)
        for k in range(6):
            link.send_sync()
            rogue.send(frame(can_map.SYNC_COB_ID, bytes([200 + k])))
            link.wait_tpdo(0.5)
            link.send_outputs((0.0, 0.0))
            link.poll(0.01)
        conflicts = link.take_conflicts()
    assert link.counters.foreign_sync == 6
    assert any(d.startswith("plant EMCY SYNC_CONFLICT") for d in conflicts)
    assert node.counters.sync_conflicts >= 5 and link.counters.conflict_emcys == 1


@pytest.mark.timeout(30)
def test_a_new_controller_recovers_the_node_from_a_rogue_nmt_stop() -> None:
    """Before: a rogue NMT STOP left the node STOPPED and the next controller could
    not start it. Now start_node resets the node's communication first."""
    with virtual_rig() as (link, node, rogue, channel):
        link.start_node(timeout=2.0, sample_period_s=0.005)
        run_ticks(link, 3)
        rogue.send(frame(can_map.NMT_COB_ID, can_map.encode_nmt(NmtCommand.STOP, 1)))
        deadline = time.monotonic() + 2.0
        while node.state is not NmtState.STOPPED and time.monotonic() < deadline:
            time.sleep(0.002)
        assert node.state is NmtState.STOPPED
        link.poll(0.05)
        assert link.counters.foreign_nmt == 1
        fresh = PlantLink(can.Bus(interface="virtual", channel=channel), 1)  # the next controller
        try:
            fresh.start_node(timeout=2.0, sample_period_s=0.005)
            assert node.state is NmtState.OPERATIONAL and fresh.counters.comm_resets == 1
            assert run_ticks(fresh, 5) == 5
        finally:
            fresh.bus.shutdown()


@pytest.mark.timeout(30)
def test_a_stock_master_cannot_switch_the_watchdog_off_and_is_seen() -> None:
    """A stock canopen master with the shipped EDS writes 0x2003 = 0 while our
    controller runs: the node aborts it (0x08000022), the link reports the foreign SDO."""
    with virtual_rig() as (link, node, _, channel):
        link.start_node(timeout=2.0, sample_period_s=0.005)
        network = canopen.Network()
        network.connect(interface="virtual", channel=channel)
        try:
            remote = network.add_node(1, str(EDS))
            with pytest.raises(canopen.SdoAbortedError) as err:
                remote.sdo["SYNC watchdog periods"].raw = 0
            assert err.value.code == 0x08000022
            assert remote.sdo["SYNC watchdog periods"].raw == 5
        finally:
            network.disconnect()
        run_ticks(link, 3)
    assert node.counters.watchdog_disable_refused == 1
    assert link.counters.foreign_sdo >= 2  # the write and the read back
    assert int(EmcyCode.SYNC_CONFLICT) not in node.active_faults


@pytest.mark.timeout(30)
def test_a_foreign_sync_stream_cannot_hold_the_valves_open_for_a_frozen_controller() -> None:
    """The controller sets RPDO1's event timer to the watchdog time at start;
    when it freezes while a rogue keeps sending SYNC (raw frames, 5 ms, 30 of
    them), the plant's watchdog trips on the missing RPDO1 all the same."""
    with virtual_rig() as (link, node, rogue, _):
        link.start_node(timeout=2.0, sample_period_s=0.005)
        assert node.rpdo_timeout_s == pytest.approx(0.025)  # 5 periods of 5 ms, as 0x2003 says
        assert run_ticks(link, 5) == 5 and not node.watchdog_tripped
        for k in range(30):  # the controller is frozen; the rogue's SYNC keeps coming
            rogue.send(frame(can_map.SYNC_COB_ID, bytes([100 + k])))
            time.sleep(0.005)
        assert node.watchdog_tripped and node.counters.rpdo_timeouts == 1
        assert node.outputs_v.tolist() == [0.0, 0.0]
        run_ticks(link, 3)  # the controller thaws: its RPDO1 releases the valves
        assert not node.watchdog_tripped
        link.poll(0.05)
        conflicts = link.take_conflicts()
    assert any(d.startswith("foreign sync") for d in conflicts)
    assert any(e.code == EmcyCode.RPDO_TIMEOUT and e.vendor[1] == 1 for e in link.emergencies)


class _Wire:
    """A bus stand-in keeping what a link sends (a direct one, like the co-simulation's wire, offers ``send_frame``)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self.kinds: set[str] = set()

    def send(self, msg: Any, timeout: float | None = None) -> None:
        assert not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame) and msg.dlc == len(msg.data)
        self.kinds.add(type(msg).__name__)
        self.frames.append((msg.arbitration_id, bytes(msg.data)))

    def recv(self, timeout: float | None = None) -> None:
        return None


class _DirectWire(_Wire):
    def send_frame(self, cob_id: int, data: bytes) -> None:
        self.kinds.add("send_frame")
        self.frames.append((cob_id, bytes(data)))


class _Forwarding:
    """A wrapper forwarding what it does not define (as the recording wire does): frames go through its send."""

    def __init__(self, inner: _Wire) -> None:
        self.inner = inner
        self.sent = 0

    def send(self, msg: Any, timeout: float | None = None) -> None:
        self.sent += 1
        self.inner.send(msg, timeout)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_a_wrapper_that_forwards_send_frame_still_sees_every_frame() -> None:
    """The link takes the direct path only when the wire's class offers send_frame, so a
    forwarding wrapper around a direct wire (the co-simulation's recording) gets every frame."""
    wrapper = _Forwarding(_DirectWire())
    link = PlantLink(wrapper, 1)  # type: ignore[arg-type]
    link.send_output_codes(100, -100)
    link.send_sync()
    assert wrapper.sent == 2 and wrapper.inner.kinds == {"Message"}
