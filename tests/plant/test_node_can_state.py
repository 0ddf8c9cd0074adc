"""The plant node reports its own CAN error state as CiA 301 says, seen by a
stock canopen master (its EmcyConsumer) on a ``ralfwire`` bus in one
process: EMCY 0x8120 on error passive, 0x8140 after bus off, the error reset
0x0000 when error active again, and the error register's communication bit
(bit 4) set exactly while the node is not error active. The node runs
run_node's steps by hand on a manual wire clock, so the timeline is exact."""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Callable

import can
import canopen

from plant_emulator.canopen_node import CanopenNode, NodeConfig, run_node
from plant_emulator.canopen_node.can_state import error_state_reader
from plant_emulator.canopen_node.stepper import serve_once
from protocol.can_map import Emergency, decode_emcy
from service_kit.can_wire.arbitration import ErrorInjection
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus
from tests.plant.support import EDS, FakeApp

BITRATE = 500_000


class Driver:
    """The node served a step at a time on a manual clock (:func:`plant_emulator.canopen_node.stepper.serve_once`), its error register noted."""

    def __init__(self, node: CanopenNode, bus: WireBus, clock: ManualWireClock) -> None:
        self.node, self.bus, self.clock = node, bus, clock
        self.read_state = error_state_reader(bus)
        assert self.read_state is not None
        self.registers: list[tuple[ErrorState, int]] = []

    def serve(self) -> None:
        serve_once(self.bus, self.node, self.clock.now_ns() / 1e9)
        assert self.read_state is not None
        self.registers.append((self.read_state(), self.node.error_register))

    def run_out(self) -> None:
        self.clock.run(self.serve)


def _wait_for(pred: Callable[[], bool], timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end and not pred():
        time.sleep(0.005)
    return bool(pred())


def test_error_passive_and_bus_off_reported_to_a_canopen_master() -> None:
    channel = f"can-state-{uuid.uuid4().hex}"
    clock = ManualWireClock()
    node = CanopenNode(FakeApp(), NodeConfig(watchdog_periods=0))
    bus = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="plant")
    network = canopen.Network()
    network.connect(interface="ralfwire", channel=channel, bitrate=BITRATE, clock=clock, node="master")
    try:
        remote = network.add_node(1, str(EDS))
        drive = Driver(node, bus, clock)
        wire = bus.wire
        # Phase 1: the boot-up fails 16 times: TEC 128, error passive; the EMCY (0x081 wins
        # arbitration over 0x701) goes through, TEC 127: error active, the error reset follows.
        wire.inject_errors(ErrorInjection(arbitration_id=0x701, node="plant", count=16))
        drive.run_out()
        assert _wait_for(lambda: len(remote.emcy.log) == 2)
        assert [(e.code, e.register) for e in remote.emcy.log] == [(0x8120, 0x11), (0x0000, 0x00)]
        assert (ErrorState.PASSIVE, 0x11) in drive.registers
        # Phase 2: the SDO answer fails 17 times: from TEC 126 error passive at once, bus off
        # at 262. Nothing is sent while bus off; 128 x 11 recessive bits later the node is
        # error active: the held EMCY 0x8120, then 0x8140 and the error reset.
        wire.inject_errors(ErrorInjection(node="plant", count=17))
        network.send_message(0x601, bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0]))
        drive.run_out()
        assert _wait_for(lambda: len(remote.emcy.log) == 5)
        assert [(e.code, e.register) for e in remote.emcy.log[2:]] == [(0x8120, 0x11), (0x8140, 0x11), (0x0000, 0x00)]
        assert any(s is ErrorState.BUS_OFF for s, _ in drive.registers)
        for state, register in drive.registers:  # bit 4 (communication) exactly while not error active
            assert bool(register & 0x10) == (state is not ErrorState.ACTIVE), (state, register)
        assert node.error_register == 0 and bus.error_status().state is ErrorState.ACTIVE
        assert int(node.od.get(0x1003, 1)) & 0xFFFF == 0x8140  # the error history, newest first
        assert remote.emcy.active == []
    finally:
        network.disconnect()
        bus.shutdown()


def test_a_bus_without_error_state_changes_nothing() -> None:
    bus = can.Bus(interface="virtual", channel=f"can-state-{uuid.uuid4().hex}")
    try:
        assert error_state_reader(bus) is None
    finally:
        bus.shutdown()


def test_run_node_reports_what_its_bus_tells() -> None:
    """The node's own loop (run_node, in its thread, on its own clock) reads the
    bus's error state: the wire's manual clock holds the node error passive until
    the loop has queued its EMCY 0x8120; once that has gone through (TEC 127)
    the loop sends the error reset."""
    channel = f"can-state-{uuid.uuid4().hex}"
    clock = ManualWireClock()
    node = CanopenNode(FakeApp(), NodeConfig(watchdog_periods=0))
    bus = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="plant")
    master = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="master")
    wire = bus.wire
    wire.inject_errors(ErrorInjection(arbitration_id=0x701, node="plant", count=16))
    stop = threading.Event()
    thread = threading.Thread(target=run_node, args=(bus, node, stop), kwargs={"max_wait_s": 0.005}, daemon=True)
    thread.start()
    try:
        assert _wait_for(lambda: 0x701 in wire.queued_ids())  # the boot-up
        while bus.error_status().state is not ErrorState.PASSIVE:
            t = clock.next_event_ns()
            assert t is not None
            clock.advance_to(t)
        assert _wait_for(lambda: 0x081 in wire.queued_ids())  # the loop saw error passive: EMCY 0x8120
        emcys: list[Emergency] = []

        def delivered() -> bool:  # the wire runs on, a little idle time at a time, until the reset came
            clock.run(lambda: None)
            clock.advance_to(clock.now_ns() + 10 * 2000)
            emcys.extend(decode_emcy(m.data) for m in iter(lambda: master.recv(0), None) if m.arbitration_id == 0x081)
            return len(emcys) >= 2

        assert _wait_for(delivered)
        assert [(e.code, e.register) for e in emcys] == [(0x8120, 0x11), (0x0000, 0x00)]
    finally:
        stop.set()
        thread.join(10.0)
        bus.shutdown()
        master.shutdown()


def _emcys(frames: list[can.Message]) -> list[tuple[int, int]]:
    return [(e.code, e.register) for e in (decode_emcy(f.data) for f in frames if f.arbitration_id == 0x081)]


def test_every_transition_and_an_nmt_reset() -> None:
    """The reporter on its own: bus off seen without error passive before it (a loop
    that woke too late) sends nothing until the recovery; an NMT reset while error
    passive clears the fault, and the next look raises it again."""
    node = CanopenNode(FakeApp(), NodeConfig(watchdog_periods=0))
    node.poll(0.0)  # boot-up
    node.can_error_state(ErrorState.ACTIVE)
    assert _emcys(node.poll(0.0)) == [] and node.error_register == 0
    node.can_error_state(ErrorState.BUS_OFF)
    assert _emcys(node.poll(0.0)) == [] and node.error_register == 0x11
    assert int(node.od.get(0x1003, 1)) & 0xFFFF == 0x8120  # recorded in the history, not sendable
    node.can_error_state(ErrorState.ACTIVE)
    assert _emcys(node.poll(0.0)) == [(0x8140, 0x11), (0x0000, 0x00)]
    node.can_error_state(ErrorState.PASSIVE)
    node.can_error_state(ErrorState.PASSIVE)
    assert _emcys(node.poll(0.0)) == [(0x8120, 0x11)]  # once per entry
    node.handle(can.Message(arbitration_id=0x000, data=bytes([0x82, 1]), is_extended_id=False), 0.0)  # NMT reset communication
    node.poll(0.0)
    node.can_error_state(ErrorState.PASSIVE)
    assert _emcys(node.poll(0.0)) == [(0x8120, 0x11)]
    node.can_error_state(ErrorState.ACTIVE)
    assert _emcys(node.poll(0.0)) == [(0x0000, 0x00)]
