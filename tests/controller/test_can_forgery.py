"""The controller's link against forged plant frames and foreign SDO writes,
on a ``virtual`` bus with the real node behind its runner and a rogue
station on the same channel: a second TPDO1 per SYNC, a heartbeat STOPPED or
boot-up while the plant runs, a forged conflict EMCY, a foreign SDO write of
0x1017 / 0x1019 (raw frames and a stock ``canopen`` master). Each is
detected with its evidence, and a real stop is still a stop. Bounded in
frames and time; the subject is what arrives, not how fast."""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import can
import canopen
import pytest

from controller.plant_link import PlantFault, PlantLink
from plant_emulator.canopen_node import CanopenNode, NodeConfig, run_node
from protocol.can_map import EmcyCode, NmtCommand, NmtState, encode_emcy, encode_heartbeat, encode_nmt
from tests.plant.support import FakeApp

EDS = Path(__file__).resolve().parents[2] / "protocol" / "ralf_io.eds"
NMT, EMCY, TPDO1, SDO_RX, HB = 0x000, 0x081, 0x181, 0x601, 0x701
FORGED_WORDS = struct.pack("<4h", 32767, 32767, -32768, -32768)  # full scale: what drove the valves to 10 V


def frame(cob_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=cob_id, data=data, is_extended_id=False)


@contextmanager
def rig(cfg: NodeConfig | None = None) -> Iterator[tuple[PlantLink, CanopenNode, can.BusABC, str]]:
    """The real node served by its runner, the controller's link (started), a rogue station."""
    channel = f"ralf-forgery-{uuid.uuid4().hex}"
    buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
    node = CanopenNode(FakeApp(), cfg or NodeConfig(heartbeat_ms=20))
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(buses[0], node, stop), daemon=True)
    thread.start()
    try:
        link = PlantLink(buses[1], 1)
        link.start_node(timeout=5.0, sample_period_s=0.005)
        yield link, node, buses[2], channel
    finally:
        stop.set()
        thread.join(10.0)
        for bus in buses:
            bus.shutdown()


def tick(link: PlantLink) -> tuple[int, ...] | None:
    link.send_sync()
    words = link.wait_tpdo(5.0)
    link.send_outputs((0.0, 0.0))
    return words


def settle(link: PlantLink, node: CanopenNode, done: object) -> None:
    """Poll until ``done()`` (bounded): the node thread may be held a while on a loaded host."""
    deadline = time.monotonic() + 5.0
    while not done() and time.monotonic() < deadline:  # type: ignore[operator]
        link.poll(0.01)


@pytest.mark.timeout(60)
def test_a_second_tpdo1_for_each_sync_is_a_conflict_with_both_frames() -> None:
    with rig() as (link, node, rogue, _):
        assert [tick(link) is not None for _ in range(3)] == [True] * 3 and link.take_conflicts() == []
        for _ in range(10):  # the rogue answers every SYNC with full-scale words
            link.send_sync()
            rogue.send(frame(TPDO1, FORGED_WORDS))
            link.wait_tpdo(5.0)
            link.send_outputs((0.0, 0.0))
        settle(link, node, lambda: node.counters.impersonated["tpdo1"] == 10 and link.counters.impersonations >= 1)
        conflicts = link.take_conflicts()
    assert link.counters.surplus_tpdos >= 9  # every SYNC answered twice (the last pair may straddle the end)
    surplus = [c for c in conflicts if c.startswith("surplus tpdo1")]
    assert surplus and all("id 0x181" in c for c in surplus)
    assert any("ff 7f ff 7f 00 80 00 80" in c for c in surplus)  # the forged words, as evidence
    assert node.counters.impersonated["tpdo1"] == 10  # and the plant says so itself (EMCY 0x8150)
    assert any(c.startswith("impersonation: the plant reports a frame id 0x181") for c in conflicts)


@pytest.mark.timeout(60)
@pytest.mark.parametrize("state", [NmtState.STOPPED, NmtState.BOOT_UP])
def test_a_spoofed_heartbeat_while_the_plant_runs_is_a_forgery_not_a_stop(state: NmtState) -> None:
    with rig() as (link, node, rogue, _):
        tick(link)
        rogue.send(frame(HB, encode_heartbeat(state)))
        answered = [tick(link) is not None for _ in range(5)]
        settle(link, node, lambda: link.counters.forged_heartbeats >= 1)
        conflicts = link.take_conflicts()
    assert answered == [True] * 5 and link.node_state is NmtState.OPERATIONAL  # never taken for a stop
    assert link.counters.forged_heartbeats == 1
    (forged,) = [c for c in conflicts if c.startswith("forged heartbeat")]
    assert f"heartbeat {state.name} id 0x701 [{state.value:02x}]" in forged
    assert node.counters.impersonated["heartbeat"] == 1 and node.state is NmtState.OPERATIONAL


@pytest.mark.timeout(60)
def test_a_real_stop_is_still_a_stop() -> None:
    """A rogue's NMT STOP (a real one: the node stops) is a foreign NMT, and the
    node's STOPPED heartbeat with no TPDO1 for the next SYNC ends the run."""
    with rig() as (link, node, rogue, _):
        tick(link)
        rogue.send(frame(NMT, encode_nmt(NmtCommand.STOP, 1)))
        settle(link, node, lambda: link.counters.heartbeats > 0 and node.state is NmtState.STOPPED and len(link._held) > 0)
        link.send_sync()
        with pytest.raises(PlantFault, match="left OPERATIONAL .heartbeat says STOPPED"):
            link.wait_tpdo(0.2)
        conflicts = link.take_conflicts()
    assert any(c.startswith("foreign nmt") for c in conflicts) and link.counters.forged_heartbeats == 0


@pytest.mark.timeout(60)
def test_a_forged_conflict_emcy_is_disowned_by_the_plant() -> None:
    """Before: one forged EMCY 0xFF02 stopped the run for a SYNC conflict that never happened."""
    with rig() as (link, node, rogue, _):
        tick(link)
        rogue.send(frame(EMCY, encode_emcy(EmcyCode.SYNC_CONFLICT, 0x81, b"\x07")))
        for _ in range(3):
            tick(link)
        settle(link, node, lambda: link.counters.forged_emcys >= 1)
        conflicts = link.take_conflicts()
    assert link.counters.forged_emcys == 1 and link.counters.conflict_emcys == 0
    assert [c for c in conflicts if c.startswith("forged emcy: EMCY SYNC_CONFLICT id 0x081 [02 ff 81 07")]
    assert not [c for c in conflicts if "the plant sees a second master" in c]


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("index", "request_bytes"), [(0x1017, bytes([0x2B, 0x17, 0x10, 0, 0, 0, 0, 0])), (0x1019, bytes([0x2F, 0x19, 0x10, 0, 0, 0, 0, 0]))])
def test_a_foreign_sdo_write_of_a_communication_object_is_undone(index: int, request_bytes: bytes) -> None:
    """Before: 0x1017 = 0 (heartbeat off) or 0x1019 = 0 (SYNC counter refused) ended the run."""
    with rig() as (link, node, rogue, _):
        tick(link)
        before = node.od.get(index)
        rogue.send(frame(SDO_RX, request_bytes))
        answered = [tick(link) is not None for _ in range(5)]
        settle(link, node, lambda: node.od.get(index) == before)
        conflicts = link.take_conflicts()
        answered += [tick(link) is not None for _ in range(5)]
    assert node.od.get(index) == before  # written back by the link
    assert link.counters.comm_restores == 1 and link.counters.foreign_sdo == 1
    assert any(c.startswith(f"foreign sdo: a write of 0x{index:04X}:0 = 0") and "id 0x601" in c for c in conflicts)
    assert node.counters.comm_writes[f"0x{index:04X}"] == 2  # the plant's view: the foreign write and the link's
    assert answered[-5:] == [True] * 5


@pytest.mark.timeout(60)
def test_a_stock_master_switching_the_heartbeat_off_is_seen_and_undone() -> None:
    with rig() as (link, node, _, channel):
        tick(link)
        network = canopen.Network()
        network.connect(interface="virtual", channel=channel)
        try:
            remote = network.add_node(1, str(EDS))
            remote.sdo["Producer heartbeat time"].raw = 0
            assert remote.sdo["Producer heartbeat time"].raw == 0  # the node took it
        finally:
            network.disconnect()
        for _ in range(3):
            tick(link)
        settle(link, node, lambda: node.od.get(0x1017) == 20)
        conflicts = link.take_conflicts()
    assert node.od.get(0x1017) == 20 and link.counters.comm_restores == 1
    assert link.counters.foreign_sdo == 2 and link.counters.foreign_sdo_reads == 1  # the read back is only counted
    assert [c for c in conflicts if c.startswith("foreign sdo: a write of 0x1017:0 = 0")]


@pytest.mark.timeout(60)
def test_late_answers_in_a_burst_are_not_a_surplus() -> None:
    """A plant held up for 30 SYNCs answers them in one burst: late, not forged.
    Before, two SYNCs of credit made the third of such a burst a "surplus" and
    stopped a loaded real-time run. One more TPDO1 than SYNCs is a surplus."""
    channel = f"ralf-burst-{uuid.uuid4().hex}"
    node_bus, link_bus, rogue = (can.Bus(interface="virtual", channel=channel) for _ in range(3))
    node = CanopenNode(FakeApp(), NodeConfig(heartbeat_ms=20, watchdog_periods=0))
    hold, stop = threading.Event(), threading.Event()
    held: list[can.Message] = []

    def serve() -> None:  # the node's runner, except that SYNCs wait while ``hold`` is set
        while not stop.is_set():
            msg = node_bus.recv(0.005)
            now = time.monotonic()
            out = []
            if msg is not None and msg.arbitration_id == 0x080 and hold.is_set():
                held.append(msg)
            elif msg is not None:
                out = node.handle(msg, now)
            if not hold.is_set() and held:
                for m in held:
                    out += node.handle(m, now)
                held.clear()
            for f in out + node.poll(now):
                node_bus.send(f)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        link = PlantLink(link_bus, 1)
        link.start_node(timeout=5.0, sample_period_s=0.005)
        tick(link)
        hold.set()
        missed = 0
        for _ in range(30):
            link.send_sync()
            missed += link.wait_tpdo(0.0) is None
        deadline = time.monotonic() + 5.0
        while len(held) < 30 and time.monotonic() < deadline:
            time.sleep(0.002)
        hold.clear()
        settle(link, node, lambda: link.counters.tpdos >= 31)
        assert missed == 30 and link.counters.tpdos == 31
        assert link.counters.surplus_tpdos == 0 and not [c for c in link.take_conflicts() if c.startswith("surplus")]
        rogue.send(frame(TPDO1, FORGED_WORDS))
        settle(link, node, lambda: link.counters.surplus_tpdos >= 1)
        assert link.counters.surplus_tpdos == 1
    finally:
        stop.set()
        thread.join(10.0)
        for bus in (node_bus, link_bus, rogue):
            bus.shutdown()
