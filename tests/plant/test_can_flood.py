"""Junk on the CAN group and frames the rig cannot carry: the node's runner
reads a junk-datagram flood at full speed with every datagram accounted for
(read and counted, or dropped by the kernel for a full buffer and counted
through ``SO_RXQ_OVFL``), CAN FD frames are counted, not silently dropped,
and both reach the node's and the link's counters (the plant's health
carries the node's). udp_multicast only inside ``.ci/loopback-netns``;
bounded in datagrams and time."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import can
import msgpack  # type: ignore[import-untyped]
import pytest

from controller.plant_link import PlantFault, PlantLink
from plant_emulator.canopen_node import CanopenNode, NodeConfig, node_can_filters, run_node
from plant_emulator.canopen_node.runner import RX_ERROR_STREAK_PAUSE
from service_kit.can_udp import LoopFreeUdpMulticastBus
from tests.plant.support import FakeApp

GROUP = "239.74.163.2"
JUNK = [b"\xc1\xc1 junk", msgpack.packb([1, 2, 3]), msgpack.packb({"arbitration_id": "SYNC", "data": 7}), b""]


class CountingStop(threading.Event):
    """The runner's stop event, counting the pauses it takes."""

    def __init__(self) -> None:
        super().__init__()
        self.waits = 0

    def wait(self, timeout: float | None = None) -> bool:
        self.waits += 1
        return super().wait(0)


class FailingBus(can.BusABC):
    """A bus whose every receive fails ``n`` times (an undecodable datagram each), then stops the runner."""

    def __init__(self, n: int, stop: threading.Event) -> None:
        self.left, self.stop_event = n, stop
        self.channel_info = "failing"
        super().__init__(channel="failing")

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.left > 0:
            self.left -= 1
            raise can.CanOperationError("could not unpack received message")
        self.stop_event.set()
        return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def test_receive_errors_are_read_back_to_back_and_each_counted() -> None:
    """Before: the runner waited 1 ms after every receive error (2,000 junk datagrams
    a second starved the plant). Now it pauses once per RX_ERROR_STREAK_PAUSE errors in
    a row (a bus failing on every call must not spin the CPU), so 10,000 errors cost
    at most 39 pauses, and every one is counted."""
    stop = CountingStop()
    node = CanopenNode(FakeApp(), NodeConfig())
    n = 10_000
    run_node(FailingBus(n, stop), node, stop)
    assert node.counters.rx_errors == n
    assert stop.waits <= n // RX_ERROR_STREAK_PAUSE


def _port() -> int:
    return 47601 + os.getpid() % 10000 // 2 * 2


@contextmanager
def udp_rig(port: int, small_buffer: bool = True) -> Iterator[tuple[PlantLink, CanopenNode, LoopFreeUdpMulticastBus]]:
    """The node on the rig's udp_multicast bus (a small receive buffer, so a flood overflows it),
    the controller's link started, then the heartbeat switched off (and no watchdog), so nothing
    but the flood is on the group while it lasts."""
    try:
        node_bus = can.Bus(interface="ralf_udp_multicast", channel=GROUP, port=port, can_filters=node_can_filters(1))
        link_bus = can.Bus(interface="ralf_udp_multicast", channel=GROUP, port=port)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    assert isinstance(node_bus, LoopFreeUdpMulticastBus)
    if small_buffer:
        node_bus.set_receive_buffer(4096)
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=20, watchdog_periods=0))
    link = PlantLink(link_bus, 1)
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(node_bus, node, stop), daemon=True)
    thread.start()
    try:
        try:
            link.start_node(timeout=5.0)
        except Exception as e:  # noqa: BLE001
            pytest.skip(f"no IPv4 multicast delivery on loopback: {e}")
        link.sdo_write(0x1017, 0, 0, 2)  # heartbeat off once started: only the flood on the group while it lasts
        yield link, node, node_bus
    finally:
        stop.set()
        thread.join(10.0)
        node_bus.shutdown()
        link_bus.shutdown()


@pytest.mark.timeout(120)
def test_a_junk_flood_is_read_at_full_speed_with_every_datagram_accounted_for() -> None:
    """4,000 junk datagrams sent back to back: on each end every one is read and counted
    (``rx_errors``) or dropped by the kernel for a full buffer and counted
    (``kernel_drops``, from SO_RXQ_OVFL); then every tick is answered. An SDO read
    after the flood marks the end of it: once answered, the node has read all that
    came before its request and the link all that came before the answer; a request
    or answer the kernel dropped on the way (a full buffer) is one more drop on one
    end, and the read is tried again."""
    port = _port()
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    attacker.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    sent = 4000
    lost_marks = 0
    try:
        with udp_rig(port) as (link, node, _):
            for k in range(sent):
                attacker.sendto(JUNK[k % len(JUNK)], (GROUP, port))
            while True:
                try:
                    assert link.sdo_read(0x1000, 0, timeout=2.0) == 0x000C0191
                    break
                except PlantFault:
                    lost_marks += 1
                    assert lost_marks < 20
            answered = 0
            for _ in range(20):
                link.send_sync()
                answered += link.wait_tpdo(5.0) is not None
                link.send_outputs((0.0, 0.0))
            link.take_conflicts()  # copies the bus's loss counters
            node_counts, link_counts = node.counters.as_dict(), link.counters.as_dict()
    finally:
        attacker.close()
    assert answered == 20
    node_seen = node_counts["rx_errors"] + node_counts["junk_frames"] + node_counts["kernel_drops"]
    link_seen = link_counts["rx_errors"] + link_counts["junk_frames"] + link_counts["kernel_drops"]
    assert node_seen >= sent and link_seen >= sent, (node_counts, link_counts)
    assert node_seen + link_seen == 2 * sent + lost_marks, (node_counts, link_counts, lost_marks)  # nothing unaccounted
    assert node_counts["kernel_drops"] > 0  # the small buffer did overflow: drops are counted, not silent


@pytest.mark.timeout(60)
def test_can_fd_frames_are_counted_not_silently_dropped() -> None:
    """A CAN FD station on the group (python-can's udp_multicast with fd): the rig's
    classic-CAN buses drop its frames and count them, and the node's counters say so."""
    port = _port() + 1000
    try:
        fd_station = can.Bus(interface="udp_multicast", channel=GROUP, port=port, fd=True)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    try:
        with udp_rig(port, small_buffer=False) as (link, node, node_bus):
            for _ in range(5):
                fd_station.send(can.Message(arbitration_id=0x080, data=bytes(range(12)), is_fd=True, is_extended_id=False))
                fd_station.send(can.Message(arbitration_id=0x601, data=bytes(16), is_fd=True, is_extended_id=False))
            deadline = time.monotonic() + 30.0  # a bound for a loaded host, not a figure
            while node_bus.fd_frames_dropped < 10 and time.monotonic() < deadline:
                time.sleep(0.01)
            for _ in range(3):
                link.send_sync()
                assert link.wait_tpdo(5.0) is not None
            link.poll(0.05)
            link.take_conflicts()
    finally:
        fd_station.shutdown()
    assert node_bus.fd_frames_dropped == 10 and node.counters.fd_frames_dropped == 10
    assert node.counters.as_dict()["fd_frames_dropped"] == 10
    assert link.counters.fd_frames_dropped == 10
