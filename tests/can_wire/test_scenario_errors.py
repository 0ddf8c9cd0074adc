"""A fault scenario's ``can_errors``: the schema (bad input refused in one
line), its injections on a ``ralfwire`` wire giving what the bus model gives
for them, and its refusal on a bus that is not ``ralfwire``."""

from __future__ import annotations

import uuid

import can
import pytest

from controller.can_errors import attach_can_errors
from protocol.errors import ConfigError
from service_kit.can_wire.arbitration import QueuedFrame, simulate
from service_kit.can_wire.bits import frame_of_message
from service_kit.can_wire.scenario_errors import CanErrorsNeedWire, attach, injections
from service_kit.can_wire.wire_bus import ManualWireClock, WireBus
from service_kit.link_faults import ScenarioError, parse_scenario

BITRATE = 500_000

YAML = """
name: can-errors
seed: 7
can_errors:
  - {identifier: 0x181, from_s: 0.005, to_s: 0.012, probability: 0.5}
  - {identifier: all, count: 3, from_s: 0.015}
"""


def test_schema_reads_yaml_and_json() -> None:
    s = parse_scenario(YAML)
    assert [(f.identifier, f.count, f.probability, f.from_s, f.to_s) for f in s.can_errors] == [(0x181, None, 0.5, 0.005, 0.012), ("all", 3, 1.0, 0.015, None)]
    j = parse_scenario('{"can_errors": [{"identifier": "0x181", "count": 2}]}', yaml_ok=False)
    assert j.can_errors[0].identifier == 0x181
    assert parse_scenario("{}", yaml_ok=False).can_errors == []  # off unless given
    per_frame = parse_scenario('{"can_errors": [{"identifier": 385, "attempts_per_frame": 2}]}', yaml_ok=False).can_errors
    assert injections(per_frame, 0)[0].first_attempts == 2 and injections(per_frame, 0)[0].count is None


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ('{"identifier": 385}', "destroys every frame for ever"),
        ('{"identifier": "0x181x", "count": 1}', "neither 'all' nor an integer"),
        ('{"identifier": 536870912, "count": 1}', "outside 0..0x1FFFFFFF"),
        ('{"count": 1, "from_s": 2, "to_s": 1}', "to_s must be after from_s"),
        ('{"count": 0}', "can_errors.0.count"),
        ('{"probability": 1.5, "count": 1}', "can_errors.0.probability"),
        ('{"count": 1, "node": "plant"}', "can_errors.0.node: Extra inputs"),
    ],
)
def test_bad_entries_refused_in_one_line(entry: str, message: str) -> None:
    with pytest.raises(ScenarioError, match=message) as info:
        parse_scenario(f'{{"can_errors": [{entry}]}}', yaml_ok=False)
    assert "\n" not in str(info.value)


def test_on_the_wire_as_in_the_bus_model() -> None:
    """A SYNC and a TPDO1 every millisecond for 20 ms, with the YAML's errors: the
    wire's deliveries, attempts and error frames equal the bus model's for the same
    injections; errors fall only in their windows and on their identifiers."""
    scenario = parse_scenario(YAML)
    clock = ManualWireClock()
    channel = f"scenario-errors-{uuid.uuid4().hex}"
    ctrl = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="controller", keep_log=True)
    plant = WireBus(channel=channel, bitrate=BITRATE, clock=clock, node="plant")
    try:
        assert attach(ctrl, scenario) == 2
        queued = []
        for k in range(20):
            t = k * 1_000_000
            clock.advance_to(t)
            for bus, node, msg in (
                (ctrl, "controller", can.Message(arbitration_id=0x080, data=bytes([k + 1]), is_extended_id=False)),
                (plant, "plant", can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False)),
            ):
                bus.send(msg)
                queued.append(QueuedFrame(node, t, frame_of_message(msg)))
        while (t := clock.next_event_ns()) is not None:
            clock.advance_to(t)
        model = simulate(queued, BITRATE, errors=injections(scenario.can_errors, scenario.seed))
        wire = ctrl.wire
        assert [(d.arbitration_id, d.start_ns, d.last_bit_ns, d.attempts) for d in wire.log] == [
            (tx.arbitration_id, tx.start_ns, tx.last_bit_ns, tx.attempts) for tx in model.transmissions
        ]
        failed = [a for a in model.attempts if not a.ok]
        assert wire.error_frames == len(failed)
        in_window = [a for a in failed if 5_000_000 <= a.start_ns < 12_000_000]
        late = [a for a in failed if a.start_ns >= 15_000_000]
        assert in_window and all(a.arbitration_id == 0x181 for a in in_window)
        assert len(late) == 3 and len(in_window) + len(late) == len(failed)
    finally:
        ctrl.shutdown()
        plant.shutdown()


def test_refused_on_a_bus_that_is_not_ralfwire() -> None:
    scenario = parse_scenario(YAML)
    bus = can.Bus(interface="virtual", channel=f"scenario-errors-{uuid.uuid4().hex}")
    try:
        assert attach(bus, None) == 0 and attach(bus, parse_scenario("{}", yaml_ok=False)) == 0
        with pytest.raises(CanErrorsNeedWire):
            attach(bus, scenario)
        with pytest.raises(ConfigError, match="need the CAN bus on ralfwire") as info:
            attach_can_errors(bus, scenario)
        assert "\n" not in str(info.value)
    finally:
        bus.shutdown()


def test_a_cosim_run_refuses_them_in_one_line() -> None:
    """The co-simulation's CAN link is no wire: a scenario with can_errors is refused, not run without them."""
    import json

    from workbench.hil import HilRig, RigRunError

    rig = HilRig(controller={"duration_s": 0.2, "tf_download_samples": 0, "fault_scenario": json.dumps({"can_errors": [{"count": 3}]})})
    with pytest.raises(RigRunError, match="can_errors need the CAN bus on ralfwire") as info:
        rig.run(0.2)
    assert "\n" not in str(info.value)
