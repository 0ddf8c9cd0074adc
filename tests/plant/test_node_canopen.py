"""The node on a bus: a standard CANopen master (the ``canopen`` package with
our EDS) drives it over python-can's ``virtual`` interface, the runner keeps
time, and the same node answers over ``udp_multicast`` between two buses."""

from __future__ import annotations

import os
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import can
import canopen
import numpy as np
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig, SdoAbortCode, node_can_filters, run_node
from plant_emulator.canopen_node.eds import apply_units
from protocol.can_map import (
    ADC12,
    DAC12,
    EmcyCode,
    NmtCommand,
    NmtState,
    decode_analog_inputs_16,
    encode_nmt,
    encode_sync,
)
from tests.plant.support import EDS, FakeApp


def wait_until(pred: Callable[[], bool], timeout: float = 1.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.002)
    return pred()


@contextmanager
def serving(bus: can.BusABC, node: CanopenNode) -> Iterator[threading.Thread]:
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(bus, node, stop), name="node", daemon=True)
    thread.start()
    try:
        yield thread
    finally:
        stop.set()
        thread.join(10.0)  # it returns within max_wait_s; 10 s leaves a loaded host its pauses
        assert not thread.is_alive(), "run_node did not return after stop"


def test_canopen_master_drives_the_node() -> None:
    channel = f"ralf-node-master-{uuid.uuid4().hex}"
    app = FakeApp(volts=(3.2, -1.1, 0.25, -9.5))
    cfg = NodeConfig(watchdog_periods=0)
    node = CanopenNode(app, cfg)
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel, receive_own_messages=False)
    try:
        remote = network.add_node(1, str(EDS))
        assert apply_units(remote.object_dictionary) > 0  # units and factors: the EDS's units file (CiA 306 has no key for them)
        with serving(node_bus, node):
            # boot-up seen by the master: PRE-OPERATIONAL
            assert wait_until(lambda: remote.nmt.state == "PRE-OPERATIONAL")

            # identity, device type and (segmented) device name by SDO
            ident = remote.sdo["Identity object"]
            assert ident["Vendor-ID"].raw == cfg.vendor_id
            assert ident["Product code"].raw == cfg.product_code
            assert ident["Revision number"].raw == cfg.revision
            assert ident["Serial number"].raw == cfg.serial_number
            assert remote.sdo[0x1000].raw == 0x000C0191
            assert remote.sdo["Manufacturer device name"].raw == cfg.device_name
            assert remote.sdo["Producer heartbeat time"].raw == 100

            # PDO configuration read back from the node matches what it sends
            remote.tpdo.read()
            remote.rpdo.read()
            t1, t2, r1 = remote.tpdo[1], remote.tpdo[2], remote.rpdo[1]
            assert (t1.cob_id, t1.enabled, t1.trans_type, t1.rtr_allowed) == (0x181, True, 1, False)
            assert [v.name for v in t1.map] == [f"Read analog input 16-bit.Analog input {i}" for i in range(1, 5)]
            assert not t2.enabled
            assert (r1.cob_id, r1.enabled, r1.trans_type) == (0x201, True, 255)
            assert [v.name for v in r1.map] == ["Write analog output 16-bit.Analog output 1", "Write analog output 16-bit.Analog output 2"]

            # NMT start; TPDO1 on SYNC carries what the app sampled
            remote.nmt.state = "OPERATIONAL"
            assert wait_until(lambda: remote.nmt.state == "OPERATIONAL", 0.5)
            got: queue.Queue[list[float]] = queue.Queue()
            t1.add_callback(lambda m: got.put([v.raw for v in m]))
            network.sync.transmit(1)
            raw = got.get(timeout=1.0)
            words = ADC12.quantize(app.volts).counts << 4
            assert raw == words.tolist()
            assert app.syncs == [1]
            np.testing.assert_allclose([v.phys for v in t1.map], app.volts, atol=ADC12.lsb_v / 2)  # the units file's factor

            # the same inputs by SDO
            ai = remote.sdo["Read analog input 16-bit"]
            assert [ai[i].raw for i in range(1, 5)] == words.tolist()

            # ADC resolution by SDO: the app is told, TPDO2/3 become valid and carry 0x6402
            remote.sdo["ADC resolution"].raw = 20
            assert app.adc_calls == [20]
            remote.tpdo.read()
            assert remote.tpdo[2].enabled and remote.tpdo[3].enabled and remote.tpdo[2].cob_id == 0x281
            wide: queue.Queue[tuple[int, list[float]]] = queue.Queue()
            for n in (1, 2, 3):
                remote.tpdo[n].add_callback(lambda m, n=n: wide.put((n, [v.phys for v in m])))
            network.sync.transmit(2)
            by_pdo = dict(wide.get(timeout=1.0) for _ in range(3))
            lsb20 = 20.0 / 2**20
            np.testing.assert_allclose(by_pdo[2] + by_pdo[3], app.volts, atol=lsb20 / 2)
            np.testing.assert_allclose(by_pdo[1], app.volts, atol=20.0 / 2**16)  # 16 MSBs

            # RPDO1 from the master's mapping: applied on receipt, in volts
            r1["Write analog output 16-bit.Analog output 1"].phys = 2.5
            r1["Write analog output 16-bit.Analog output 2"].phys = -0.75
            r1.transmit()
            assert wait_until(lambda: len(app.outputs) == 1)
            np.testing.assert_allclose(app.outputs[0], [2.5, -0.75], atol=DAC12.lsb_v / 2)

            # abort codes as a master sees them
            for call, code in (
                (lambda: remote.sdo.upload(0x6401, 9), SdoAbortCode.SUBINDEX_DOES_NOT_EXIST),
                (lambda: remote.sdo.upload(0x5555, 0), SdoAbortCode.OBJECT_DOES_NOT_EXIST),
                (lambda: remote.sdo.download(0x6401, 1, b"\x00\x00"), SdoAbortCode.WRITE_READ_ONLY),
                (lambda: remote.sdo.download(0x2001, 0, b"\x10\x00"), SdoAbortCode.LENGTH_TOO_HIGH),
            ):
                with pytest.raises(canopen.SdoAbortedError) as err:
                    call()
                assert err.value.code == code

            # clipping and the watchdog reach the master as EMCY
            remote.sdo["Valve voltage limit"].raw = 2.0
            r1["Write analog output 16-bit.Analog output 1"].phys = 5.0
            r1.transmit()
            assert wait_until(lambda: any(e.code == EmcyCode.OUTPUT_CLIPPED for e in remote.emcy.log))
            assert 2.0 - DAC12.lsb_v < app.outputs[-1][0] <= 2.0  # the largest D/A code within the limit
            remote.sdo["SYNC watchdog periods"].raw = 4  # 20 ms
            network.sync.transmit(3)
            assert wait_until(lambda: any(e.code == EmcyCode.SYNC_TIMEOUT for e in remote.emcy.log))
            assert app.watchdog == [True]
            network.sync.transmit(4)
            assert wait_until(lambda: app.watchdog == [True, False])
            assert wait_until(lambda: remote.emcy.log[-1].code == 0 and remote.emcy.active == [])
            assert remote.sdo["Error register"].raw == 0

            # STOP: heartbeat says so, SYNC gets no TPDO
            remote.nmt.state = "STOPPED"
            assert wait_until(lambda: remote.nmt.state == "STOPPED", 0.5)
            n_syncs = len(app.syncs)
            network.sync.transmit(5)
            time.sleep(0.05)
            assert len(app.syncs) == n_syncs

        c = node.counters
        assert c.malformed_total == 0 and c.internal_errors == 0 and c.app_errors == 0
        assert c.tx["tpdo1"] == 4 and c.tx["tpdo2"] == 3 and c.sdo.uploads >= 20
    finally:
        network.disconnect()
        node_bus.shutdown()


class _WaitingBus:
    """A bus whose ``recv(timeout)`` lets ``timeout`` of a fake clock pass (nothing
    ever arrives) and which stamps each sent frame with that clock: the runner's
    scheduling, judged without the host's timing."""

    def __init__(self, stop: threading.Event, until_s: float) -> None:
        self.now = 0.0
        self.sent: list[tuple[float, can.Message]] = []
        self.waits: list[float] = []
        self.stop, self.until_s = stop, until_s

    def clock(self) -> float:
        return self.now

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self.waits.append(float(timeout or 0.0))
        self.now += float(timeout or 0.0)
        if self.now >= self.until_s:
            self.stop.set()
        return None

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append((self.now, msg))


def test_runner_keeps_heartbeat_time_and_stops_promptly() -> None:
    """The runner waits exactly until the node's next deadline (never past
    ``max_wait_s``, so a stop is seen within it): heartbeats go out on their
    50 ms grid with no drift, the first one the boot-up."""
    stop = threading.Event()
    bus = _WaitingBus(stop, until_s=1.0)
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=50))
    run_node(bus, node, stop, bus.clock, max_wait_s=0.02)  # type: ignore[arg-type]
    beats = [(t, m) for t, m in bus.sent if m.arbitration_id == 0x701]
    assert bytes(beats[0][1].data) == b"\x00"
    times = np.array([t for t, _ in beats[1:]])
    assert len(times) == 20
    assert np.allclose(times, 0.05 * np.arange(1, 21), atol=1e-9), times  # on the grid: no drift
    assert max(bus.waits) <= 0.02 + 1e-12 and min(bus.waits) >= 0.0


def test_runner_serves_heartbeats_on_a_real_bus_and_stops() -> None:
    """The same loop on a python-can virtual bus in real time: heartbeats
    arrive and stop() ends it (counts only: no timing is asserted)."""
    channel = f"ralf-node-runner-{uuid.uuid4().hex}"
    node_bus = can.Bus(interface="virtual", channel=channel)
    listener = can.Bus(interface="virtual", channel=channel)
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=20))
    beats = 0
    try:
        with serving(node_bus, node):  # joins the runner thread on exit (asserts it ended)
            deadline = time.monotonic() + 30.0
            while beats < 3 and time.monotonic() < deadline:
                msg = listener.recv(0.1)
                beats += msg is not None and msg.arbitration_id == 0x701
    finally:
        node_bus.shutdown()
        listener.shutdown()
    assert beats >= 3


UDP_GROUP = "239.74.163.2"


def test_node_over_udp_multicast() -> None:
    pytest.importorskip("msgpack", reason="udp_multicast needs msgpack")
    port = 47000 + os.getpid() % 10000 // 2 * 2  # test-unique, away from the default 43113
    try:
        node_bus = can.Bus(interface="udp_multicast", channel=UDP_GROUP, port=port, can_filters=node_can_filters(1))
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    try:
        master = can.Bus(
            interface="udp_multicast",
            channel=UDP_GROUP,
            port=port,
            can_filters=[{"can_id": 0x181, "can_mask": 0x7FF, "extended": False}, {"can_id": 0x701, "can_mask": 0x7FF, "extended": False}],
        )
    except Exception as e:  # noqa: BLE001
        node_bus.shutdown()
        pytest.skip(f"udp_multicast unavailable on this host: {e}")
    app = FakeApp()
    node = CanopenNode(app, NodeConfig(heartbeat_ms=20, watchdog_periods=0))
    try:
        with serving(node_bus, node):
            boot = master.recv(1.0)
            if boot is None:
                pytest.skip("no IPv4 multicast delivery on loopback (route 224.0.0.0/4 missing?)")
            assert boot.arbitration_id == 0x701
            master.send(can.Message(arbitration_id=0x000, data=encode_nmt(NmtCommand.START, 1), is_extended_id=False))
            deadline = time.monotonic() + 1.0
            while node.state is not NmtState.OPERATIONAL and time.monotonic() < deadline:
                time.sleep(0.002)
            assert node.state is NmtState.OPERATIONAL
            expected = (ADC12.quantize(app.volts).counts << 4).tolist()
            for counter in range(1, 21):
                master.send(can.Message(arbitration_id=0x080, data=encode_sync(counter), is_extended_id=False))
                while True:  # heartbeats interleave; our own SYNC/NMT echoes are filtered out
                    msg = master.recv(1.0)
                    assert msg is not None, f"no TPDO1 for SYNC {counter}"
                    if msg.arbitration_id == 0x181:
                        break
                assert decode_analog_inputs_16(msg.data).tolist() == expected
        c = node.counters
        assert app.syncs == list(range(1, 21)) and c.sync_gaps == 0
        assert c.rx["own_cob_id"] >= 20  # the node's own TPDO echoes, counted and ignored
        assert c.malformed_total == 0 and c.rx_errors == 0 and c.internal_errors == 0
    finally:
        node_bus.shutdown()
        master.shutdown()
