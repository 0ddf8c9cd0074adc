"""The XCP slave without a rig: its DAQ packets, its overload counting, and
bad input on its ports (counted, answered or dropped, never a crash), with
pyxcp as the master that must still work afterwards."""

from __future__ import annotations

import random
import socket
import struct
import time
from typing import Any

import pytest

from controller.xcp_table import controller_layout, xcp_events
from service_kit.xcp.memory import Write, WriteRefused
from service_kit.xcp.packets import FRAME_HEADER, Cmd, Err, frame, split_frames
from service_kit.xcp.server import Server
from service_kit.xcp.slave import Slave, SlaveInfo, Snapshot
from service_kit.xcp.tcp import TcpServer
from service_kit.xcp.udp import UdpServer
from tests.xcp.rig_client import master, wait_for

LAYOUT = controller_layout()


def make_slave(written: list[Any] | None = None) -> Slave:
    def calibrate(changes: list[Write]) -> None:
        if written is None:
            raise WriteRefused(Err.ERR_MEMORY_OVERFLOW, "full")
        written.append([(w.variable.name, w.raw, w.physical) for w in changes])

    values = [7.5 if v.name == "kp1" else 0 for v in LAYOUT.variables]
    return Slave(LAYOUT, SlaveInfo("TEST", "/x/test.a2l", xcp_events(0.005)), calibrate, LAYOUT.pack(values))


def cmd(slave: Slave, *fields: Any, fmt: str = "") -> bytes:
    packet = struct.pack("<" + fmt, *fields)
    response = slave.handle(packet)
    assert response is not None
    return response


def image(tick: int) -> bytes:
    return LAYOUT.pack([tick if v.name == "tick" else (0.25 * tick if v.name == "phi1" else 0) for v in LAYOUT.variables])


def test_daq_lists_timestamps_prescaler_and_events() -> None:
    s = make_slave([])
    assert cmd(s, Cmd.CONNECT, 0, fmt="BB")[0] == 0xFF
    tick, phi1 = LAYOUT.by_name["tick"], LAYOUT.by_name["phi1"]
    for packet in (
        (Cmd.FREE_DAQ,),
        (Cmd.ALLOC_DAQ, 0, 2),
        (Cmd.ALLOC_ODT, 0, 0, 2),
        (Cmd.ALLOC_ODT, 0, 1, 1),
        (Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, 1),
        (Cmd.ALLOC_ODT_ENTRY, 0, 0, 1, 1),
        (Cmd.ALLOC_ODT_ENTRY, 0, 1, 0, 1),
    ):
        fmt = {1: "B", 3: "BBH", 4: "BBHB", 5: "BBHBB"}[len(packet)]
        assert cmd(s, *packet, fmt=fmt) == b"\xff", packet
    entries = ((0, 0, tick), (0, 1, phi1), (1, 0, tick))
    for daq, odt, v in entries:
        assert cmd(s, Cmd.SET_DAQ_PTR, 0, daq, odt, 0, fmt="BBHBB") == b"\xff"
        assert cmd(s, Cmd.WRITE_DAQ, 0xFF, v.size, 0, v.address, fmt="BBBBI") == b"\xff"
    assert cmd(s, Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 2, 0, fmt="BBHHBB") == b"\xff"  # timestamps, event 0, every 2nd
    assert cmd(s, Cmd.SET_DAQ_LIST_MODE, 0x00, 1, 1, 1, 0, fmt="BBHHBB") == b"\xff"  # event 1, no timestamp
    assert cmd(s, Cmd.SET_DAQ_LIST_MODE, 0x02, 1, 1, 1, 0, fmt="BBHHBB") == bytes((0xFE, Err.ERR_OUT_OF_RANGE))  # no STIM
    assert cmd(s, Cmd.START_STOP_DAQ_LIST, 2, 0, fmt="BBH") == b"\xff\x00"
    assert cmd(s, Cmd.START_STOP_DAQ_LIST, 2, 1, fmt="BBH") == b"\xff\x02"  # its first PID follows list 0's two ODTs
    assert s.on_snapshot(Snapshot(1, 0, image(0))) == []  # not started yet
    assert cmd(s, Cmd.START_STOP_SYNCH, 1, fmt="BB") == b"\xff"
    assert cmd(s, Cmd.GET_STATUS, fmt="B")[1] & 0x40
    out = [s.on_snapshot(Snapshot(1 | (2 if k == 3 else 0), 5000 * k, image(k))) for k in range(5)]
    expected_0 = lambda k: [struct.pack("<BII", 0, 5000 * k, k), struct.pack("<Bd", 1, 0.25 * k)]  # noqa: E731
    assert out[0] == expected_0(0) and out[1] == [] and out[2] == expected_0(2) and out[4] == expected_0(4)
    assert out[3] == [struct.pack("<BI", 2, 3)]  # list 1 on the interrupt event only; list 0's prescaler skips tick 3
    assert cmd(s, Cmd.GET_DAQ_CLOCK, fmt="B") == b"\xff\x00\x00\x00" + struct.pack("<I", 20000)
    assert cmd(s, Cmd.SET_DAQ_LIST_MODE, 0x10, 0, 0, 1, 0, fmt="BBHHBB") == bytes((0xFE, Err.ERR_DAQ_ACTIVE))
    assert cmd(s, Cmd.START_STOP_SYNCH, 0, fmt="BB") == b"\xff"
    assert s.on_snapshot(Snapshot(3, 0, image(9))) == []


def test_writes_checked_and_handed_over() -> None:
    written: list[Any] = []
    s = make_slave(written)
    cmd(s, Cmd.CONNECT, 0, fmt="BB")
    kp1, kp2, tick = LAYOUT.by_name["kp1"], LAYOUT.by_name["kp2"], LAYOUT.by_name["tick"]
    assert cmd(s, Cmd.SHORT_DOWNLOAD, 16, 0, 0, kp1.address, 1.0, 2.0, fmt="BBBBIdd") == b"\xff"
    assert written == [[("kp1", 1.0, 1000.0), ("kp2", 2.0, 2000.0)]]
    assert s.values([kp1, kp2]) == [1000.0, 2000.0]
    assert cmd(s, Cmd.SHORT_DOWNLOAD, 8, 0, 0, kp2.address, 1e4, fmt="BBBBId") == bytes((0xFE, Err.ERR_OUT_OF_RANGE))
    assert cmd(s, Cmd.SHORT_DOWNLOAD, 4, 0, 0, tick.address, 1, fmt="BBBBII") == bytes((0xFE, Err.ERR_WRITE_PROTECTED))
    assert cmd(s, Cmd.SHORT_DOWNLOAD, 8, 0, 0, kp2.address, 1.0, fmt="BBBBId")[:1] == b"\xff"
    full = make_slave(None)  # the loop's queue refuses: the slave answers its code and keeps its image
    cmd(full, Cmd.CONNECT, 0, fmt="BB")
    assert cmd(full, Cmd.SHORT_DOWNLOAD, 8, 0, 0, kp1.address, 1.0, fmt="BBBBId") == bytes((0xFE, Err.ERR_MEMORY_OVERFLOW))
    assert full.values([kp1]) == [7500.0]
    assert s.counters.writes_refused == 2 and full.counters.writes_refused == 1


class _Stuck(Server):
    """A transport whose socket takes nothing."""

    def _serve(self, timeout: float) -> None:
        time.sleep(timeout)

    def _send_dto(self, packet: bytes) -> bool:
        return False


def test_unsent_dtos_and_a_full_queue_are_counted() -> None:
    s = make_slave([])
    for packet, fmt in (
        ((Cmd.CONNECT, 0), "BB"),
        ((Cmd.ALLOC_DAQ, 0, 1), "BBH"),
        ((Cmd.ALLOC_ODT, 0, 0, 1), "BBHB"),
        ((Cmd.ALLOC_ODT_ENTRY, 0, 0, 0, 1), "BBHBB"),
        ((Cmd.SET_DAQ_PTR, 0, 0, 0, 0), "BBHBB"),
        ((Cmd.WRITE_DAQ, 0xFF, 4, 0, LAYOUT.base), "BBBBI"),
        ((Cmd.SET_DAQ_LIST_MODE, 0, 0, 0, 1, 0), "BBHHBB"),
        ((Cmd.START_STOP_DAQ_LIST, 1, 0), "BBH"),
    ):
        assert cmd(s, *packet, fmt=fmt)[0] == 0xFF
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    server = _Stuck(s, sock, capacity=3)
    for k in range(5):  # the thread is not running: the queue takes 3
        server.offer(Snapshot(1, k, image(k)))
    assert s.counters.snapshots_dropped == 2
    server.start()
    assert wait_for(lambda: s.counters.daq_overloads == 3, 30)
    server.close()
    assert s.counters.dtos_sent == 0


def garbage(rng: random.Random) -> bytes:
    """A datagram or stream piece: random bytes, frames of bad length, cut-short or unknown commands."""
    kind = rng.randrange(6)
    if kind == 0:
        return rng.randbytes(rng.randrange(0, 40))
    if kind == 1:
        return FRAME_HEADER.pack(rng.choice((0, 256, 4000, 65535)), 0) + rng.randbytes(8)
    if kind == 2:
        return frame(bytes((rng.choice([c.value for c in Cmd]),)), 0)  # a known command with no fields
    if kind == 3:
        return frame(bytes((rng.randrange(0xC0, 0xF0),)) + rng.randbytes(rng.randrange(0, 7)), 0)  # mostly unknown
    if kind == 4:
        return frame(rng.randbytes(rng.randrange(1, 255)), 0)
    return frame(struct.pack("<BBBBI", Cmd.SHORT_UPLOAD, rng.randrange(256), 0, 0, rng.randrange(1 << 32)), 0)[: rng.randrange(2, 12)]


@pytest.mark.parametrize("protocol", ["UDP", "TCP"])
def test_bad_input_counted_and_survived(protocol: str) -> None:
    slave = make_slave([])
    server: Server = UdpServer(slave, "127.0.0.1", 0) if protocol == "UDP" else TcpServer(slave, "127.0.0.1", 0)
    server.start()
    rng = random.Random(20261207)
    try:
        connect = frame(bytes((Cmd.CONNECT, 0)), 0)
        for round_ in range(20):
            kind = socket.SOCK_DGRAM if protocol == "UDP" else socket.SOCK_STREAM
            with socket.socket(socket.AF_INET, kind) as sock:
                sock.settimeout(5.0)
                sock.connect(("127.0.0.1", server.port))
                if round_ % 2:
                    sock.send(connect)  # connected: the commands are answered, not dropped
                    assert sock.recv(4096)[4] == 0xFF
                for _ in range(25):
                    try:
                        sock.send(garbage(rng))
                    except OSError:  # TCP: the slave closed a stream it could no longer read
                        break
                if protocol == "TCP":
                    try:
                        sock.shutdown(socket.SHUT_WR)
                        while sock.recv(4096):  # the slave's answers, up to its close
                            pass
                    except OSError:  # closed by the slave already
                        pass
        c = slave.counters
        assert wait_for(lambda: c.malformed > 0 and c.dropped_unconnected > 0, 10)
        if protocol == "UDP":
            assert c.unknown_commands > 0 and c.negative_responses > 0
        assert c.internal_errors == 0
        with master(server.port, protocol) as x:  # pyxcp still gets its answers
            assert struct.unpack("<d", x.shortUpload(8, LAYOUT.by_name["kp1"].address)) == (7.5,)
    finally:
        server.close()
    assert c.internal_errors == 0


def test_split_frames() -> None:
    data = frame(b"\xff\x00", 1) + frame(b"\xfd", 2) + FRAME_HEADER.pack(3, 3) + b"\xf5"
    packets, used = split_frames(data, 255)
    assert packets == [(1, b"\xff\x00"), (2, b"\xfd")] and used == len(data) - 5
