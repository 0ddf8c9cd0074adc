"""What the slave refuses, each with XCP's error code as pyxcp (a master nobody
here wrote) receives it: addresses outside the map, DAQ commands out of
sequence, DAQ lists beyond the slave's memory, a second master on TCP; and a
master that vanishes mid-DAQ (counted; the slave serves the next one)."""

from __future__ import annotations

import socket
import struct
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pyxcp.config import create_application_from_config
from pyxcp.daq_stim import DaqList
from pyxcp.master import Master
from pyxcp.master.errorhandler import SystemExit as XcpError
from pyxcp.types import XcpResponseError

from controller.xcp_table import controller_layout
from service_kit.xcp.server import Server
from service_kit.xcp.slave import MAX_DAQ, MAX_ODT_ENTRIES, MAX_PID, Snapshot
from service_kit.xcp.tcp import TcpServer
from service_kit.xcp.udp import UdpServer
from tests.xcp.rig_client import Collect, master, wait_for
from tests.xcp.test_slave import image, make_slave

LAYOUT = controller_layout()
ERR_OUT_OF_RANGE, ERR_ACCESS_DENIED, ERR_SEQUENCE, ERR_MEMORY_OVERFLOW = 0x22, 0x24, 0x29, 0x30


def refused_code(call: Any) -> int:
    with pytest.raises(XcpError) as info:
        call()
    return int(info.value.error_code)


def raw_code(call: Any) -> int:
    """The error code of a negative response with pyxcp's error handling off."""
    with pytest.raises(XcpResponseError) as info:
        call()
    return int(info.value.get_error_code())


@pytest.fixture(params=["UDP", "TCP"])
def served(request: pytest.FixtureRequest) -> Iterator[tuple[Server, str]]:
    protocol = str(request.param)
    slave = make_slave([])
    server: Server = UdpServer(slave, "127.0.0.1", 0) if protocol == "UDP" else TcpServer(slave, "127.0.0.1", 0)
    server.start()
    try:
        yield server, protocol
    finally:
        server.close()


def test_addresses_outside_the_map(served: tuple[Server, str]) -> None:
    server, protocol = served
    with master(server.port, protocol) as x:
        assert refused_code(lambda: x.shortUpload(4, LAYOUT.end)) == ERR_ACCESS_DENIED
        assert refused_code(lambda: x.shortUpload(4, LAYOUT.base - 4)) == ERR_ACCESS_DENIED
        assert refused_code(lambda: x.shortUpload(8, LAYOUT.end - 4)) == ERR_ACCESS_DENIED  # runs over the end
        x.setMta(LAYOUT.end, 0)
        assert refused_code(lambda: x.upload(4)) == ERR_ACCESS_DENIED
        assert refused_code(lambda: x.shortDownload(LAYOUT.end, 0, struct.pack("<d", 1.0))) == ERR_ACCESS_DENIED
        x.setMta(0x10, 0)
        assert refused_code(lambda: x.download(b"\x01\x02")) == ERR_ACCESS_DENIED
        assert refused_code(lambda: x.shortUpload(4, 0x1000, 1)) == ERR_OUT_OF_RANGE  # address extension 1: none
        assert struct.unpack("<d", x.shortUpload(8, LAYOUT.by_name["kp1"].address)) == (7.5,)  # the master still served
    assert server.counters.writes_refused == 6 and server.counters.calibration_writes == 0


def test_daq_commands_out_of_sequence(served: tuple[Server, str]) -> None:
    server, protocol = served
    tick = LAYOUT.by_name["tick"]
    with master(server.port, protocol, raw_errors=True) as x:
        x.freeDaq()
        assert raw_code(lambda: x.allocOdt(0, 1)) == ERR_SEQUENCE  # before ALLOC_DAQ
        assert raw_code(lambda: x.allocOdtEntry(0, 0, 1)) == ERR_SEQUENCE  # before ALLOC_DAQ
        assert raw_code(lambda: x.startStopDaqList(1, 0)) == ERR_SEQUENCE  # no list set
        assert raw_code(lambda: x.writeDaq(0xFF, 4, 0, tick.address)) == ERR_SEQUENCE  # no SET_DAQ_PTR
        x.allocDaq(1)
        assert raw_code(lambda: x.allocOdtEntry(0, 0, 1)) == ERR_SEQUENCE  # before ALLOC_ODT
        x.allocOdt(0, 1)
        assert raw_code(lambda: x.allocDaq(1)) == ERR_SEQUENCE  # ALLOC_DAQ again without FREE_DAQ
        x.allocOdtEntry(0, 0, 1)
        assert raw_code(lambda: x.writeDaq(0xFF, 4, 0, tick.address)) == ERR_SEQUENCE  # still no SET_DAQ_PTR
        x.setDaqPtr(0, 0, 0)
        x.writeDaq(0xFF, 4, 0, tick.address)
        assert raw_code(lambda: x.writeDaq(0xFF, 4, 0, tick.address)) == ERR_OUT_OF_RANGE  # past the ODT's one entry
        assert raw_code(lambda: x.setDaqPtr(0, 1, 0)) == ERR_OUT_OF_RANGE  # no ODT 1
        x.setDaqListMode(0x10, 0, 0, 1, 0)
        x.startStopDaqList(1, 0)


def test_daq_lists_beyond_the_slaves_memory(served: tuple[Server, str]) -> None:
    server, protocol = served
    with master(server.port, protocol, raw_errors=True) as x:
        x.freeDaq()
        assert raw_code(lambda: x.allocDaq(MAX_DAQ + 1)) == ERR_MEMORY_OVERFLOW
        x.allocDaq(2)
        assert raw_code(lambda: x.allocOdt(0, MAX_PID + 2)) == ERR_MEMORY_OVERFLOW  # more ODTs than PIDs
        x.allocOdt(0, 200)
        assert raw_code(lambda: x.allocOdt(1, 60)) == ERR_MEMORY_OVERFLOW  # 260 in all
        x.allocOdt(1, 4)
        for odt in range(MAX_ODT_ENTRIES // 255):
            x.allocOdtEntry(0, odt, 255)
        assert raw_code(lambda: x.allocOdtEntry(0, 10, 255)) == ERR_MEMORY_OVERFLOW  # past the entries' memory
        x.freeDaq()  # everything given back
        x.allocDaq(MAX_DAQ)


def test_a_second_master_on_tcp_is_refused() -> None:
    slave = make_slave([])
    server = TcpServer(slave, "127.0.0.1", 0)
    server.start()
    try:
        with master(server.port, "TCP") as first:
            app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": server.port, "protocol": "TCP"}}})
            app.transport.layer = "ETH"
            app.transport.timeout = 0.5
            app.general.connect_retries = 0
            with pytest.raises(Exception) as info:  # the connection closed at once: pyxcp gets no answer
                with Master("eth", config=app) as second:
                    second.connect()
            assert not isinstance(info.value, AssertionError)
            assert wait_for(lambda: slave.counters.masters_refused == 1, 10)
            assert struct.unpack("<d", first.shortUpload(8, LAYOUT.by_name["kp1"].address)) == (7.5,)  # the first unaffected
    finally:
        server.close()
    assert slave.counters.sessions_lost == 0 and slave.counters.internal_errors == 0


def daq_on_tick() -> DaqList:
    tick = LAYOUT.by_name["tick"]
    return DaqList(name="tick", event_num=0, stim=False, enable_timestamps=True, measurements=[("tick", tick.address, 0, "U32")], priority=0, prescaler=1)


def test_a_master_that_vanishes_mid_daq(served: tuple[Server, str]) -> None:
    """The master's socket closes without DISCONNECT while DAQ runs: on TCP the
    session is counted lost and its lists freed; on UDP (no connection) the DTOs
    go on to the last address, counted as sent. Samples keep being taken without
    blocking or loss, and the next master is served."""
    server, protocol = served
    policy = Collect([daq_on_tick()])
    app = create_application_from_config({"Transport": {"Eth": {"host": "127.0.0.1", "port": server.port, "protocol": protocol}}})
    app.transport.layer = "ETH"
    app.transport.timeout = 2.0
    x = Master("eth", config=app, policy=policy).__enter__()  # left without its __exit__: no DISCONNECT
    x.connect()
    policy.setup()
    policy.start()
    for k in range(50):
        server.offer(Snapshot(1, 5000 * k, image(k)))
    assert wait_for(lambda: len(policy.samples) == 50, 30)
    x.transport.close()  # gone: no DISCONNECT, no STOP
    c = server.counters
    k = 50
    if protocol == "UDP":  # no connection to lose: the DTOs go on to its address, sent and counted, until a master's command moves them
        for k in range(50, 250):
            server.offer(Snapshot(1, 5000 * k, image(k)))  # never blocks
        assert wait_for(lambda: c.dtos_sent == 250, 30)
    else:  # the connection's end is the session's: its lists freed, nothing more sent
        deadline = time.monotonic() + 30
        while c.sessions_lost == 0 and time.monotonic() < deadline:
            server.offer(Snapshot(1, 5000 * k, image(k)))  # never blocks
            k += 1
            time.sleep(0.005)
        assert c.sessions_lost == 1 and not server.slave.daq
    assert c.snapshots_dropped == 0 and c.internal_errors == 0
    with master(server.port, protocol) as again:
        assert struct.unpack("<I", again.shortUpload(4, LAYOUT.by_name["tick"].address))[0] <= k


def test_tcp_port_closed_is_not_a_master() -> None:
    """A probe that connects and closes at once: not a session (nothing lost)."""
    slave = make_slave([])
    server = TcpServer(slave, "127.0.0.1", 0)
    server.start()
    try:
        with socket.create_connection(("127.0.0.1", server.port), timeout=5):
            pass  # closed: the slave reads its end before it judges the next connection
        with master(server.port, "TCP") as x:
            x.getStatus()
    finally:
        server.close()
    assert slave.counters.sessions_lost == 0
