"""The controller notices CAN error states (controller.can_errors): the plant
node's EMCY 0x8120/0x8140, sent by the real node over ``ralfwire`` with
injected errors, and its own bus's state; the ``can_error_passive`` monitor
acts on them by its policy (count by default, degrade, stop)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from types import SimpleNamespace

import pytest

from controller.monitors import Monitors, MonitorStop
from controller.plant_link import PlantLink
from controller.tick_policy import TickPolicy
from plant_emulator.canopen_node import CanopenNode, NodeConfig
from protocol.setting_groups import Policies
from service_kit.can_wire.arbitration import ErrorInjection
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus
from tests.plant.support import FakeApp
from tests.plant.test_node_can_state import Driver

BITRATE = 500_000


@contextmanager
def rig(policy: str | None) -> Iterator[tuple[Driver, PlantLink, TickPolicy, list[bool]]]:
    clock = ManualWireClock()
    channel = f"can-error-policy-{uuid.uuid4().hex}"
    plant_bus = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="plant")
    ctrl_bus = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="controller")
    try:
        drive = Driver(CanopenNode(FakeApp(), NodeConfig(watchdog_periods=0)), plant_bus, clock)
        link = PlantLink(ctrl_bus)
        policies = Policies() if policy is None else Policies.model_validate({"can_error_passive": policy})
        tick = TickPolicy(Monitors(policies.as_dict()), link, 0.005, 1.0, SimpleNamespace(overruns=0))
        yield drive, link, tick, []
    finally:
        plant_bus.shutdown()
        ctrl_bus.shutdown()


def run_ticks(drive: Driver, link: PlantLink, tick: TickPolicy, active: list[bool]) -> None:
    """Every wire event a tick: the node serves, the controller reads the bus and checks;
    a last tick once the last frame's intermission has passed (its counters change at its end)."""
    n = 0
    idle = False
    while True:
        drive.serve()
        link.poll(0.0)
        tick.after_tick(n, False, 0.0, "")
        active.append("can_error_passive" in tick.monitors.active)
        t = drive.clock.next_event_ns()
        if t is None:
            if idle:
                return
            idle, t = True, drive.clock.now_ns() + 3 * 1_000_000_000 // BITRATE
        drive.clock.advance_to(t)
        n += 1


def test_default_policy_counts_and_goes_on() -> None:
    with rig(None) as (drive, link, tick, active):
        assert tick.monitors.policies["can_error_passive"] == "count"
        drive.bus.wire.inject_errors(ErrorInjection(arbitration_id=0x701, node="plant", count=16))
        run_ticks(drive, link, tick, active)
        assert link.counters.plant_can_error_passive == 1 and link.counters.plant_can_bus_off_recoveries == 0
        assert tick.monitors.episodes["can_error_passive"] == 1
        assert True in active and active[-1] is False  # cleared by the plant's error reset
        assert not tick.monitors.degraded


def test_degrade_while_the_plant_is_error_passive_and_after_bus_off() -> None:
    with rig("degrade") as (drive, link, tick, active):
        drive.bus.wire.inject_errors(ErrorInjection(node="plant", count=32))
        degraded: list[bool] = []
        n = 0
        while True:
            drive.serve()
            link.poll(0.0)
            tick.after_tick(n, False, 0.0, "")
            degraded.append(tick.monitors.degraded)
            t = drive.clock.next_event_ns()
            if t is None:
                break
            drive.clock.advance_to(t)
            n += 1
        assert link.counters.plant_can_bus_off_recoveries == 1
        assert any(degraded) and not degraded[-1]
        assert tick.monitors.episodes["can_error_passive"] == 1  # one episode: error passive, bus off, recovered


def test_stop_ends_the_run_naming_the_emcy() -> None:
    with rig("stop") as (drive, link, tick, active):
        drive.bus.wire.inject_errors(ErrorInjection(arbitration_id=0x701, node="plant", count=16))
        with pytest.raises(MonitorStop, match="0x8120"):
            run_ticks(drive, link, tick, active)


def test_own_bus_error_passive() -> None:
    with rig("warn") as (drive, link, tick, active):
        drive.bus.wire.inject_errors(ErrorInjection(arbitration_id=0x080, node="controller", count=16))
        link.send_sync()
        run_ticks(drive, link, tick, active)
        assert link.counters.own_can_error_passive == 1 and link.counters.own_can_bus_off == 0
        assert tick.monitors.episodes["can_error_passive"] == 1
        assert "controller's CAN controller is error-passive" in (tick.monitors.last or "")
        assert active[-1] is False


def test_nothing_on_a_bus_without_error_states() -> None:
    import can

    bus = can.Bus(interface="virtual", channel=f"can-error-policy-{uuid.uuid4().hex}")
    try:
        link = PlantLink(bus)
        assert link.can_errors.condition() is None
        monitors = Monitors(Policies().as_dict())
        assert "can_error_passive" not in monitors.episodes  # runs without CAN error states keep their counters
    finally:
        bus.shutdown()
