"""service_kit/can_udp.py: a udp_multicast bus that does not read its own
frames back, checked against python-can's stock ``udp_multicast`` bus on the
same group and port (the reference nobody here wrote)."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator

import can
import pytest

from protocol.settings import CommonSettings
from service_kit.can_udp import FRAME_PREFIX, JUNK_PER_READ, LoopFreeUdpMulticastBus, own_frame_filter
from service_kit.transport import open_can_bus

GROUP = "239.74.163.2"


def _port(k: int) -> int:
    return 46001 + (os.getpid() % 5000) * 2 + k


def _frames(bus: can.BusABC, timeout: float = 0.3) -> list[can.Message]:
    out = []
    while (msg := bus.recv(timeout)) is not None:
        out.append(msg)
        timeout = 0.05
    return out


@pytest.fixture
def buses(request: pytest.FixtureRequest) -> Iterator[tuple[LoopFreeUdpMulticastBus, LoopFreeUdpMulticastBus, can.BusABC]]:
    port = _port(0)
    kernel = getattr(request, "param", True)
    try:
        stock = can.Bus(interface="udp_multicast", channel=GROUP, port=port, hop_limit=0)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    a = LoopFreeUdpMulticastBus(channel=GROUP, port=port, hop_limit=0, kernel_filter=kernel)
    b = LoopFreeUdpMulticastBus(channel=GROUP, port=port, hop_limit=0, kernel_filter=kernel)
    probe = can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False)
    stock.send(probe)
    if not _frames(a, 1.0):
        for bus in (a, b, stock):
            bus.shutdown()
        pytest.skip("no IPv4 multicast delivery on loopback")
    _frames(b), _frames(stock)
    yield a, b, stock
    for bus in (a, b, stock):
        bus.shutdown()


@pytest.mark.parametrize("buses", [True, False], ids=["kernel-filter", "software-filter"], indirect=True)
def test_wire_compatible_with_stock_udp_multicast_and_own_frames_stay_out(buses: tuple[LoopFreeUdpMulticastBus, LoopFreeUdpMulticastBus, can.BusABC]) -> None:
    a, b, stock = buses
    sent = [can.Message(arbitration_id=0x80 + i, data=bytes(range(i)), is_extended_id=False) for i in range(9)]
    sent.append(can.Message(arbitration_id=0x1ABCDE, data=b"\x01", is_extended_id=True))
    for msg in sent:
        a.send(msg)
    for reader in (b, stock):  # a loop-free peer and python-can's own bus decode every frame alike
        got = _frames(reader)
        assert [(m.arbitration_id, m.is_extended_id, bytes(m.data), m.dlc) for m in got] == [
            (m.arbitration_id, m.is_extended_id, bytes(m.data), m.dlc) for m in sent
        ]
        assert all(m.timestamp > 1e9 for m in got)  # the kernel's receive time, as udp_multicast gives
    assert _frames(a, 0.2) == []  # its own frames never come back
    back = can.Message(arbitration_id=0x181, data=b"\x10\x20", is_extended_id=False)
    stock.send(back)
    for reader in (a, b):
        assert [(m.arbitration_id, bytes(m.data)) for m in _frames(reader)] == [(0x181, b"\x10\x20")]
    if a.kernel_filter:
        assert a.own_frames_dropped == 0  # dropped before the socket: nothing to count here
    else:
        assert a.own_frames_dropped == len(sent)  # read, recognised by sender address, dropped undecoded


def test_malformed_datagram_is_an_operation_error_not_a_crash(buses: tuple[LoopFreeUdpMulticastBus, LoopFreeUdpMulticastBus, can.BusABC]) -> None:
    """A datagram that begins as python-can's frames do and does not decode
    raises CanOperationError (as python-can's bus does); one that does not
    even begin so is junk, counted and skipped before decoding."""
    a, _, stock = buses
    junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        junk.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        junk.sendto(FRAME_PREFIX + b"\xc1not msgpack", (GROUP, _port(0)))
        with pytest.raises(can.CanOperationError):
            a.recv(1.0)
        for _ in range(JUNK_PER_READ + 3):
            junk.sendto(b"\xc1not msgpack", (GROUP, _port(0)))
        stock.send(can.Message(arbitration_id=0x101, data=b"\x01", is_extended_id=False))
        assert [m.arbitration_id for m in _frames(a)] == [0x101]
        assert a.junk_frames == JUNK_PER_READ + 3
    finally:
        junk.close()
    stock.send(can.Message(arbitration_id=0x100, data=b"\x01", is_extended_id=False))
    assert [m.arbitration_id for m in _frames(a)] == [0x100]  # and the bus goes on


def test_every_frame_python_can_packs_begins_with_the_frame_prefix() -> None:
    from can.interfaces.udp_multicast.utils import pack_message

    for msg in (
        can.Message(arbitration_id=0x80, data=b"", is_extended_id=False),
        can.Message(arbitration_id=0x1FFFFFFF, data=bytes(8), is_extended_id=True),
        can.Message(arbitration_id=0x181, is_remote_frame=True, is_extended_id=False),
        can.Message(arbitration_id=0x181, data=bytes(64), is_fd=True, bitrate_switch=True, channel="x", timestamp=1e9),
    ):
        assert pack_message(msg).startswith(FRAME_PREFIX)


def test_filter_program_drops_only_the_exact_source() -> None:
    prog = own_frame_filter(("127.0.0.1", 40000), socket.AF_INET)
    assert len(prog) == 2 * 2 + 2  # port, one address word; drop; accept
    prog6 = own_frame_filter(("::1", 40000), socket.AF_INET6)
    assert len(prog6) == 2 * 5 + 2  # port, four address words
    with pytest.raises(OSError):
        own_frame_filter(("not an address", 1), socket.AF_INET)


def test_open_can_bus_picks_the_loop_free_bus_unless_told_not_to() -> None:
    port = _port(0) + 1
    try:
        bus = open_can_bus(CommonSettings(can_port=port))
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    try:
        assert isinstance(bus, LoopFreeUdpMulticastBus)
    finally:
        bus.shutdown()
    stock = open_can_bus(CommonSettings(can_port=port, can_udp={"own_frame_filter": False}))
    try:
        assert not isinstance(stock, LoopFreeUdpMulticastBus)
        assert type(stock).__module__.startswith("can.interfaces.udp_multicast")
    finally:
        stock.shutdown()


def test_registered_as_a_python_can_interface() -> None:
    port = _port(0) + 1
    try:
        bus = can.Bus(interface="ralf_udp_multicast", channel=GROUP, port=port, hop_limit=0)
    except Exception as e:  # noqa: BLE001
        if "ralf_udp_multicast" in str(e):
            raise
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    try:
        assert isinstance(bus, LoopFreeUdpMulticastBus)
    finally:
        bus.shutdown()


def test_receive_own_messages_hands_its_frames_back_and_says_so() -> None:
    from controller.plant_link import echoing_bus

    port = _port(0) + 1
    try:
        own = LoopFreeUdpMulticastBus(channel=GROUP, port=port, hop_limit=0, receive_own_messages=True)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    quiet = LoopFreeUdpMulticastBus(channel=GROUP, port=port, hop_limit=0)
    try:
        own.send(can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False))
        got = _frames(own, 1.0)
        if not got:
            pytest.skip("no IPv4 multicast delivery on loopback")
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x7FF, b"probe")]
        assert not own.kernel_filter and own.own_frames_dropped == 0
        assert echoing_bus(own) and not echoing_bus(quiet)  # the controller matches echoes only where they come back
        assert [m.arbitration_id for m in _frames(quiet)] == [0x7FF]  # the peer saw it once
        quiet.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        assert [m.arbitration_id for m in _frames(own)] == [0x181]  # the peer's frame reaches it
        assert _frames(quiet, 0.2) == []  # and the peer, without the option, never reads its own
    finally:
        own.shutdown()
        quiet.shutdown()
