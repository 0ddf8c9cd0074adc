"""Error frames on the simulated rig's CAN wire (workbench/cosim_wire.py, workbench/lockstep_wire.py):
a fault scenario's ``can_errors`` in simulated seconds, the plant node's error state reported by
EMCY, the controller's monitor and policy, the co-simulation equal to the one-process lockstep rig."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest

from protocol import can_map
from service_kit.can_wire.error_state import RECOVERY_RUN, RECOVERY_SEQUENCES, ErrorState
from workbench.cosim import run_cosim
from workbench.cosim_wire import PLANT

CONTROLLER = {"duration_s": 1.0, "tf_download_samples": 0}
WIRE = {"can_bitrate": 1_000_000}
TPDO1 = can_map.cob_ids(can_map.DEFAULT_NODE_ID)["tpdo1"]
BUS_OFF = {"seed": 3, "can_errors": [{"identifier": TPDO1, "from_s": 0.5, "to_s": 0.506, "note": "every attempt of the plant's TPDO1 for 6 ms"}]}
MIXED = {
    "seed": 5,
    "can_errors": [
        {"identifier": "all", "probability": 0.3, "from_s": 0.2, "to_s": 0.4, "echo_bits": 2},
        {"identifier": TPDO1, "attempts_per_frame": 1, "from_s": 0.6, "to_s": 0.7},
        {"identifier": TPDO1, "from_s": 0.8, "to_s": 0.806},
    ],
}


def _controller(scenario: dict[str, Any], **extra: Any) -> dict[str, Any]:
    return {**CONTROLLER, "fault_scenario": json.dumps(scenario), **extra}


def _emcys_of(changes: list[Any]) -> list[int]:
    """The EMCYs CiA 301 gives the plant's changes of error state (docs/can-errors.md's table)."""
    codes, state, raised = [], ErrorState.ACTIVE, False
    for c in changes:
        if c.state is state:
            continue
        if c.state is ErrorState.PASSIVE:
            codes.append(0x8120)
            raised = True
        elif c.state is ErrorState.ACTIVE:
            codes += [0x8140, 0x0000] if state is ErrorState.BUS_OFF else [0x0000]
            raised = False
        elif not raised:  # bus off straight from error active: 0x8120 recorded, not sendable
            raised = True
        state = c.state
    return codes


def _columns(run: Any) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in run.controller.record.to_columns().items()}


def test_a_bus_off_of_the_plant_recovers_after_128_times_11_recessive_bits_and_is_reported_in_order() -> None:
    run = run_cosim(controller=_controller(BUS_OFF), common=WIRE)
    assert run.result.error is None
    errors = run.can_bus["errors"]
    assert errors["nodes"][PLANT] == {"error_passive": 2, "bus_off": 1, "state": "error-active", "tec": 0, "rec": 0}
    changes = run.controller.plant.bus.bus.nodes[PLANT].changes
    assert [c.tec for c in changes[:16]] == [8 * k for k in range(1, 17)]  # rule 3: +8 per error up to error passive
    assert changes[0].time_ns >= 500_000_000  # the window starts at 0.5 simulated seconds
    off = next(c for c in changes if c.state is ErrorState.BUS_OFF)
    back = changes[changes.index(off) + 1]
    assert back.state is ErrorState.ACTIVE and (back.tec, back.rec) == (0, 0)
    bit_ns = 1_000  # 1 Mbit/s; the bus-off error frame's flag (6), delimiter (8) and intermission (3) end at +17 bits
    assert back.time_ns - off.time_ns == (6 + 8 + 3) * bit_ns + (RECOVERY_SEQUENCES - 1) * RECOVERY_RUN * bit_ns
    codes = [e.code for e in run.controller.plant.emergencies]
    # error passive (its EMCY gets through: TEC 127, error active, error reset), passive again, bus off, recovered, error reset
    assert codes == _emcys_of(changes) == [0x8120, 0x0000, 0x8120, 0x8140, 0x0000]
    counters = run.result.counters
    assert counters["plant_can_error_passive"] == 2 and counters["plant_can_bus_off_recoveries"] == 1


def test_stop_policy_ends_the_run_naming_the_emcy_and_zeroes_the_valves() -> None:
    run = run_cosim(controller=_controller(BUS_OFF, policies="can_error_passive=stop"), common=WIRE)
    assert run.result.error is not None and "0x8120" in run.result.error
    assert run.result.ticks < 200 and run.result.counters["valves_zeroed"] == 1


def test_cosim_equals_the_one_process_lockstep_rig_with_errors() -> None:
    """Random and windowed errors, failed TPDO1s and a bus-off: the same record bit for bit, the same wire figures."""
    from workbench.composition import run_in_process

    cosim = run_cosim(controller=_controller(MIXED), common=WIRE)
    one = run_in_process(controller=_controller(MIXED), common=WIRE)
    assert cosim.result.error is None and one.result.error is None
    assert cosim.can_bus["errors"]["error_frames"] > 40 and cosim.can_bus["errors"]["nodes"][PLANT]["bus_off"] == 1
    assert one.can_bus == cosim.can_bus and cosim.can_bus["late_tpdo1"] > 0  # the errors cost the control loop samples
    wall = {"heartbeats"}  # the node's heartbeat runs on the wall clock in the lockstep rig, beside the wire
    assert {k: v for k, v in one.result.counters.items() if k not in wall} == {k: v for k, v in cosim.result.counters.items() if k not in wall}
    assert [e.code for e in one.controller.plant.emergencies] == [e.code for e in cosim.controller.plant.emergencies]
    a, b = _columns(cosim), _columns(one)
    assert a.keys() == b.keys()
    for name in a:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_the_rig_takes_them_as_a_fault_scenario_and_counts_them() -> None:
    from workbench.hil import HilRig

    record = HilRig(clock="cosim", common=WIRE, faults=BUS_OFF, controller={"tf_download_samples": 0}, duration_s=1.0).run()
    assert record.counters["plant_can_error_passive"] == 2 and record.counters["plant_can_bus_off_recoveries"] == 1
    assert record.can_bus is not None and record.can_bus["errors"]["nodes"][PLANT]["bus_off"] == 1


def test_without_errors_the_figures_have_no_error_part() -> None:
    run = run_cosim(controller=dict(CONTROLLER), common=WIRE)
    assert "errors" not in run.can_bus


def test_without_a_bit_rate_they_are_refused_in_one_line() -> None:
    from workbench.hil import HilRig, RigRunError

    with pytest.raises(RigRunError, match="can_errors need the CAN bus on ralfwire") as info:
        HilRig(clock="cosim", faults=BUS_OFF, controller={"tf_download_samples": 0}, duration_s=0.2).run()
    assert "\n" not in str(info.value)
