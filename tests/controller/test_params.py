"""The controller's parameter path (controller/params.py) without a rig: its
checks are the XCP map's (compared with the map's own answer to the same
bytes), the OATF's guards, the queue's bound, the schedule's tick arithmetic."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from controller.config import build_trajectory, law_config
from controller.dsp_side import ConfigChangeTaken
from controller.input_monitors import InputMonitorChecks
from controller.loop import ControlLaw
from controller.params import PENDING_CAPACITY, ParamPath, ParamRefused, first_tick
from controller.xcp_table import controller_layout
from protocol.errors import ConfigError
from protocol.messages import ParamChanged, decode
from protocol.param_schedule import parse_param_schedule
from protocol.settings import ControllerSettings
from service_kit.xcp.memory import WriteRefused
from service_kit.xcp.packets import Err


def _path(schedule: object = "", **settings: object) -> tuple[ParamPath, list[ConfigChangeTaken], list[bytes]]:
    s = ControllerSettings(**settings)  # type: ignore[arg-type]
    changes: list[ConfigChangeTaken] = []
    sent: list[bytes] = []
    path = ParamPath(ControlLaw(law_config(s), build_trajectory(s)), s.sample_period_s, changes, parse_param_schedule(schedule), publish=sent.append)  # type: ignore[arg-type]
    return path, changes, sent


@pytest.mark.parametrize(
    ("name", "value"), [("kp1", 8000.0), ("kp1", -1.0), ("ki2", 1e6), ("ki2", 1.0000001e6), ("oatf_zeta", math.nan), ("oatf_zeta", math.inf)]
)
def test_the_check_is_the_xcp_maps(name: str, value: float) -> None:
    """The path takes exactly what the map takes for the same raw bytes, and refuses with the map's code."""
    path, _, _ = _path()
    layout = controller_layout()
    v = layout.by_name[name]
    data = struct.pack("<d", value / v.factor)
    try:
        expected = layout.check_write(v.address, data)
    except WriteRefused as exc:
        with pytest.raises(ParamRefused) as info:
            path.writes(f"controller.{name}", value)
        assert info.value.code == exc.code == Err.ERR_OUT_OF_RANGE
        assert "outside its limits" in str(info.value)
    else:
        assert path.writes(f"controller.{name}", value) == expected


def test_applied_before_the_tick_recorded_and_published() -> None:
    path, changes, sent = _path()
    path.set("controller.kp2", 12000.0, "param", "tester", "r1")
    assert path.law.pi_gain("kp", 1) != 12.0  # not before its tick
    assert path.due(7)
    path.before_tick(7)
    assert path.law.pi_gain("kp", 1) == 12.0 and path.pi_gains["kp2"] == 12.0
    assert changes == [ConfigChangeTaken(7 * 0.005, "param", {"kp2": 12000.0}, "tester")]
    event = decode(ParamChanged, sent[0])
    assert (event.tick, event.kind, event.who, event.fields) == (7, "param", "tester", {"controller.kp2": 12000.0})
    assert not path.due(8)


def test_the_oatf_guards_and_the_queue_bound() -> None:
    path, _, _ = _path()
    with pytest.raises(ParamRefused, match="this run has no OATF") as info:
        path.set("controller.oatf_frequency_hz", 3.0, "param", "tester")
    assert info.value.code == Err.ERR_ACCESS_DENIED
    fixed, _, _ = _path(oatf_mode="fixed")
    with pytest.raises(ParamRefused, match="OATF design refused") as info:
        fixed.set("controller.oatf_frequency_hz", 0.5, "param", "tester")
    assert info.value.code == Err.ERR_OUT_OF_RANGE
    for _ in range(PENDING_CAPACITY):
        fixed.set("controller.kp1", 9000.0, "param", "tester")
    with pytest.raises(ParamRefused, match="too many changes") as info:
        fixed.set("controller.kp1", 9000.0, "param", "tester")
    assert info.value.code == Err.ERR_MEMORY_OVERFLOW
    assert fixed.refused == 2 and path.refused == 1


@pytest.mark.parametrize(("at_s", "tick"), [(0.0, 0), (1.0, 200), (1.0012, 201), (0.005, 1), (0.0049999, 1), (2.5031, 501)])
def test_a_step_is_taken_at_the_first_tick_at_or_after_its_time(at_s: float, tick: int) -> None:
    assert first_tick(at_s, 0.005) == tick
    assert tick * 0.005 >= at_s and (tick == 0 or (tick - 1) * 0.005 < at_s)


def test_the_schedule_groups_a_ticks_steps_and_refuses_in_one_line() -> None:
    path, changes, _ = _path([{"name": "controller.kp1", "value": 9000, "at_s": 0.5}, {"name": "controller.ki1", "value": 0, "at_s": 0.499}])
    assert not path.due(99)
    path.before_tick(100)
    assert changes == [ConfigChangeTaken(0.5, "schedule", {"kp1": 9000.0, "ki1": 0.0}, "schedule")]
    with pytest.raises(ConfigError, match=r"^param_schedule: controller\.kp1 at 1 s: controller\.kp1 = -5 mV/rad refused: outside its limits"):
        _path([{"name": "controller.kp1", "value": -5, "at_s": 1}])
    with pytest.raises(ConfigError, match=r"^param_schedule: plant\.mass at 0 s: no parameter 'plant\.mass'"):
        _path([{"name": "plant.mass", "value": 1}])


def test_the_counters_are_the_documented_ones_and_only_in_a_run_that_uses_the_path() -> None:
    from workbench.run_record_docs import PARAM_COUNTERS

    assert tuple(_path([{"name": "controller.kp1", "value": 1}])[0].counters()) == PARAM_COUNTERS
    assert _path()[0].counters() == {}


def test_the_dither_amplitude_rescales_the_same_multisine_from_its_tick() -> None:
    """The table after the change is the one a run started with that amplitude holds (its RMS the
    amplitude, numpy's); 0 mutes it; a run started without a dither refuses it."""
    from controller.excitation import DitherConfig, dither_table

    path, changes, _ = _path(dither="amplitude_v=0.1")
    law = path.law
    assert path.table()[6].name == "controller.dither_amplitude_v" and path.table()[6].value == 0.1
    path.set("controller.dither_amplitude_v", 0.3, "param", "tester")
    assert law.dither_amplitude_v == 0.1  # not before its tick
    path.before_tick(40)
    table = law._dither.reshape(-1, 2)
    assert np.array_equal(table, dither_table(DitherConfig(amplitude_v=0.3), 0.005))
    assert np.sqrt(np.mean(table**2, axis=0)) == pytest.approx([0.3, 0.3], rel=1e-9)
    assert changes == [ConfigChangeTaken(40 * 0.005, "param", {"dither_amplitude_v": 0.3}, "tester")]
    path.set("controller.dither_amplitude_v", 0.0, "param", "tester")
    path.before_tick(41)
    assert not law._dither.any() and path.value(path.variable("dither_amplitude_v")) == 0.0
    with pytest.raises(ParamRefused, match="outside its limits 0 .. 2 V"):
        path.set("controller.dither_amplitude_v", 2.5, "param", "tester")
    plain, _, _ = _path()
    with pytest.raises(ParamRefused, match=r"this run has no dither") as info:
        plain.set("controller.dither_amplitude_v", 0.1, "param", "tester")
    assert info.value.code == Err.ERR_ACCESS_DENIED
    assert math.isnan(plain.value(plain.variable("dither_amplitude_v")))


def _inputs_path(schedule: object = "") -> tuple[ParamPath, InputMonitorChecks]:
    from controller.service import make_monitors

    s = ControllerSettings(input_monitors="range=true,stuck=true,rate=true,disagree=true", param_schedule=schedule)  # type: ignore[arg-type]
    inputs = InputMonitorChecks(s.input_monitors, make_monitors(s), s.sample_period_s)
    law = ControlLaw(law_config(s), build_trajectory(s))
    return ParamPath(law, s.sample_period_s, [], parse_param_schedule(schedule), inputs=inputs), inputs


@pytest.mark.parametrize(
    ("name", "key", "value"),
    [
        ("input_stuck_samples", "stuck_samples", 7),
        ("input_extension_rate_v_s", "extension_rate_v_s", 5.0),
        ("input_deflection_rate_v_s", "deflection_rate_v_s", 40.0),
        ("input_disagree_in", "disagree_in", 0.05),
    ],
)
def test_an_input_limit_is_the_monitors_from_its_tick(name: str, key: str, value: float) -> None:
    path, inputs = _inputs_path()
    before = inputs.limits
    path.set(f"controller.{name}", value, "param", "tester")
    assert inputs.limits is before
    path.before_tick(3)
    assert getattr(inputs.limits, key) == value and path.value(path.variable(name)) == value
    assert inputs.limits.model_dump() == {**before.model_dump(), key: value}
    # the rate limits as words per tick follow (16-bit words of 20 V / 65536)
    words = (inputs.limits.extension_rate_v_s,) * 2 + (inputs.limits.deflection_rate_v_s,) * 2
    assert inputs._rate_words == pytest.approx([w * 0.005 / (20.0 / 65536) for w in words], rel=1e-12)


def test_the_input_limits_are_refused_as_their_settings_refuse_them() -> None:
    path, inputs = _inputs_path()
    with pytest.raises(ParamRefused, match="not one of its whole steps"):
        path.set("controller.input_stuck_samples", 7.5, "param", "tester")
    with pytest.raises(ParamRefused, match="outside its limits 2 .. 100000"):
        path.set("controller.input_stuck_samples", 1, "param", "tester")
    with pytest.raises(ParamRefused, match="outside its limits 0.1 .. 1e\\+06 V/s"):
        path.set("controller.input_extension_rate_v_s", 0.0, "param", "tester")
    with pytest.raises(ParamRefused, match="the low end must be below the high end") as info:
        path.set("controller.input_extension_lo_in", 20.0, "param", "tester")  # the stroke is 0 .. 20 in
    assert info.value.code == Err.ERR_OUT_OF_RANGE
    path.set("controller.input_extension_hi_in", 25.0, "param", "tester")
    with pytest.raises(ParamRefused, match="extension_range_in 22,20"):  # checked against the high end in effect, not a queued one
        path.set("controller.input_extension_lo_in", 22.0, "param", "tester")
    path.before_tick(1)
    assert inputs.limits.extension_range_in == (0.0, 25.0)
    path.before_tick(2)
    path.set("controller.input_extension_lo_in", 22.0, "param", "tester")
    path.before_tick(3)
    assert inputs.limits.extension_range_in == (22.0, 25.0) and path.refused == 5
    # a scheduled step of one tick moves both ends together, and a run without the monitors refuses them
    both, both_inputs = _inputs_path(
        [{"name": "controller.input_extension_lo_in", "value": 30, "at_s": 0.1}, {"name": "controller.input_extension_hi_in", "value": 40, "at_s": 0.1}]
    )
    both.before_tick(20)
    assert both_inputs.limits.extension_range_in == (30.0, 40.0)
    plain, _, _ = _path()
    with pytest.raises(ParamRefused, match="this run has no input monitors"):
        plain.set("controller.input_disagree_in", 0.1, "param", "tester")
    with pytest.raises(ConfigError, match=r"^param_schedule: controller\.input_stuck_samples at 0 s: this run has no input monitors"):
        _path([{"name": "controller.input_stuck_samples", "value": 5}])
