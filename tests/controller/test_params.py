"""The controller's parameter path (controller/params.py) without a rig: its
checks are the XCP map's (compared with the map's own answer to the same
bytes), the OATF's guards, the queue's bound, the schedule's tick arithmetic."""

from __future__ import annotations

import math
import struct

import pytest

from controller.config import build_trajectory, law_config
from controller.dsp_side import ConfigChangeTaken
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
