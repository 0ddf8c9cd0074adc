"""The plant node notices what it cannot prevent: frames on its own COB-IDs
(heartbeat, EMCY, TPDO1, SDO reply) that it did not send are another node
using its identifiers. Each is counted, logged at a bounded rate and
answered with EMCY CAN_ID_COLLISION (CiA 301 0x8150) carrying the frame's
evidence, so a master can tell a forged heartbeat or EMCY from the node's own.
Frame by frame on the pure node, then through the runner on a ``virtual``
bus with a stock ``canopen`` master listening."""

from __future__ import annotations

import logging
import struct
import threading
import time
import uuid

import can
import canopen
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig, run_node
from plant_emulator.canopen_node.frames import Frame
from plant_emulator.canopen_node.node import COLLISION_CLEAR_S, COLLISION_EMCY_INTERVAL_S
from protocol.can_map import (
    EmcyCode,
    NmtCommand,
    NmtState,
    decode_collision_evidence,
    decode_emcy,
    encode_emcy,
    encode_heartbeat,
    encode_nmt,
)
from tests.plant.support import EDS, FakeApp

NMT, SYNC, EMCY, TPDO1, SDO_TX, SDO_RX, HB = 0x000, 0x080, 0x081, 0x181, 0x581, 0x601, 0x701


def operational(echoes: bool = False) -> CanopenNode:
    node = CanopenNode(FakeApp(), NodeConfig(watchdog_periods=0))
    node.expect_echoes(echoes)
    node.exchange(NMT, encode_nmt(NmtCommand.START, 1), 0.0)
    return node


def collisions(frames: list[Frame]) -> list[tuple[int, int, bytes]]:
    out = []
    for f in frames:
        if f.arbitration_id == EMCY:
            e = decode_emcy(f.data)
            if e.code == EmcyCode.CAN_ID_COLLISION:
                out.append(decode_collision_evidence(e.vendor))
    return out


def test_a_forged_heartbeat_emcy_and_tpdo1_are_each_reported_with_their_evidence(caplog: pytest.LogCaptureFixture) -> None:
    node = operational()
    caplog.set_level(logging.WARNING, logger="plant_emulator.canopen_node.node")
    t = 0.01
    evidence = []
    for cob_id, data in (
        (HB, encode_heartbeat(NmtState.STOPPED)),
        (EMCY, encode_emcy(EmcyCode.SYNC_CONFLICT, 0x81, b"\x07")),
        (TPDO1, struct.pack("<4h", 32767, 32767, -32768, 0)),
        (SDO_TX, bytes([0x60, 0x17, 0x10, 0, 0, 0, 0, 0])),
    ):
        t += 2 * COLLISION_EMCY_INTERVAL_S
        evidence += collisions(node.exchange(cob_id, data, t))
    assert evidence == [(HB, 1, b"\x04"), (EMCY, 8, struct.pack("<H", EmcyCode.SYNC_CONFLICT)), (TPDO1, 8, b"\xff\x7f"), (SDO_TX, 8, b"\x60\x17")]
    c = node.counters
    assert dict(c.impersonated) == {"heartbeat": 1, "emcy": 1, "tpdo1": 1, "sdo_tx": 1} and c.as_dict()["impersonated"] == 4
    assert c.malformed_total == 0 and node.state is NmtState.OPERATIONAL  # nothing in them acts on the node
    assert int(EmcyCode.CAN_ID_COLLISION) in node.active_faults and node.error_register & 0x10  # communication bit
    (reply,) = [f for f in node.exchange(SDO_RX, struct.pack("<BHB4x", 0x40, 0x2010, 7), t) if f.arbitration_id == SDO_TX]
    assert struct.unpack_from("<I", reply.data, 4)[0] == 4  # 0x2010 sub 7 "Impersonated frames", for any master
    logged = [r.getMessage() for r in caplog.records if "did not send" in r.getMessage()]
    assert len(logged) == 4 and "0x701 [04]" in logged[0]  # once per kind per interval


def test_a_flood_of_forged_frames_gets_a_bounded_number_of_emcys_then_a_reset() -> None:
    """1,000 forged heartbeats over 1 s: every one counted, an EMCY at most every
    COLLISION_EMCY_INTERVAL_S; COLLISION_CLEAR_S after the last one the next SYNC resets it."""
    node = operational()
    out: list[Frame] = []
    t = 0.0
    for k in range(1000):
        t = 0.001 * k
        out += node.exchange(HB, encode_heartbeat(NmtState.BOOT_UP), t)
    assert node.counters.impersonated["heartbeat"] == 1000
    n_emcy = len(collisions(out))
    assert 1 <= n_emcy <= 1 + t / COLLISION_EMCY_INTERVAL_S
    quiet = node.exchange(SYNC, b"\x01", t + COLLISION_CLEAR_S / 2)
    assert [f for f in quiet if f.arbitration_id == EMCY] == []  # still within the clear time
    reset = [decode_emcy(f.data) for f in node.exchange(SYNC, b"\x02", t + COLLISION_CLEAR_S) if f.arbitration_id == EMCY]
    assert [(e.code, e.vendor[:2]) for e in reset] == [(0, struct.pack("<H", EmcyCode.CAN_ID_COLLISION))]
    assert int(EmcyCode.CAN_ID_COLLISION) not in node.active_faults


def test_on_a_bus_that_echoes_our_own_frames_only_the_foreign_ones_count() -> None:
    """python-can's udp_multicast hands the node its frames back: those match what it
    sent, in order, and are echoes; a forged heartbeat among them is still seen."""
    node = operational(echoes=True)
    sent = node.exchange(SYNC, b"\x01", 0.005) + node.poll_frames(0.2)  # TPDO1, then a heartbeat
    assert {f.arbitration_id for f in sent} == {TPDO1, HB}
    out: list[Frame] = []
    for f in sent:
        out += node.own_cob_frame(f.arbitration_id, f.data, 0.21)
    out += node.own_cob_frame(HB, encode_heartbeat(NmtState.STOPPED), 0.22)
    assert node.counters.rx["own_cob_id"] == len(sent) and node.counters.impersonated["heartbeat"] == 1
    assert collisions(out) == [(HB, 1, b"\x04")]


def test_in_stopped_the_node_counts_but_sends_no_emcy() -> None:
    node = operational()
    node.exchange(NMT, encode_nmt(NmtCommand.STOP, 1), 0.001)
    assert collisions(node.exchange(TPDO1, bytes(8), 0.002)) == []
    assert node.counters.impersonated["tpdo1"] == 1 and node.counters.emcy_suppressed >= 1


def test_sdo_writes_of_communication_objects_are_counted_by_index() -> None:
    node = CanopenNode(FakeApp(), NodeConfig())
    for index, sub, value in ((0x1017, 0, 0), (0x1019, 0, 0), (0x2003, 0, 7)):
        node.exchange(SDO_RX, struct.pack("<BHB", 0x2B if index != 0x1019 else 0x2F, index, sub) + value.to_bytes(4, "little"), 0.001)
    assert dict(node.counters.comm_writes) == {"0x1017": 1, "0x1019": 1}  # 0x2003 is not a communication object
    assert node.counters.as_dict()["comm_writes_0x1017"] == 1


@pytest.mark.timeout(30)
def test_a_stock_master_sees_the_node_disown_a_forged_heartbeat() -> None:
    """Runner on a virtual bus, a stock ``canopen`` master listening: a rogue
    station sends heartbeat STOPPED on the node's 0x701; the master's EMCY log
    gets 0x8150 with 0x701 and the state byte, and the node's heartbeat keeps
    saying OPERATIONAL."""
    channel = f"ralf-impersonation-{uuid.uuid4().hex}"
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=20, watchdog_periods=0))
    node_bus = can.Bus(interface="virtual", channel=channel)
    rogue = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network()
    network.connect(interface="virtual", channel=channel)
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(node_bus, node, stop), daemon=True)
    thread.start()
    try:
        remote = network.add_node(1, str(EDS))
        remote.nmt.state = "OPERATIONAL"
        remote.nmt.wait_for_heartbeat(5.0)
        deadline = time.monotonic() + 5.0
        while node.state is not NmtState.OPERATIONAL and time.monotonic() < deadline:
            time.sleep(0.002)
        rogue.send(can.Message(arbitration_id=HB, data=encode_heartbeat(NmtState.STOPPED), is_extended_id=False))
        emcy = remote.emcy.wait(EmcyCode.CAN_ID_COLLISION, timeout=5.0)
        assert emcy is not None
        assert decode_collision_evidence(emcy.data) == (HB, 1, b"\x04")
        assert remote.nmt.wait_for_heartbeat(5.0) == "OPERATIONAL"  # the node's own next heartbeat
    finally:
        stop.set()
        thread.join(10.0)
        network.disconnect()
        for bus in (node_bus, rogue):
            bus.shutdown()
    assert node.counters.impersonated["heartbeat"] == 1 and node.state is NmtState.OPERATIONAL
