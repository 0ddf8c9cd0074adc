"""The builder: profiles from Python and YAML, split by side and merged into a scenario."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from protocol.errors import ConfigError
from protocol.settings import ControllerSettings, PlantSettings
from workbench.stimulus import Stimulus


def test_python_profiles_split_by_side_and_load_as_settings() -> None:
    stim = Stimulus().sine("valve.u1", amplitude=0.5, f_hz=2, at_s=1).step("payload", 1.0, at_s=2.0, for_s=1.0).ramp("setpoint.phi1", to=0.05, over_s=1.0)
    frags = stim.settings()
    assert [p["input"] for p in frags["controller"]["stimulus"]] == ["valve.u1", "setpoint.phi1"]
    assert frags["plant"] == {"scenario": {"stimulus": [{"input": "payload", "shape": "step", "size": 1.0, "at_s": 2.0, "for_s": 1.0}]}}
    assert json.loads(ControllerSettings(**frags["controller"]).stimulus) == frags["controller"]["stimulus"]
    assert json.loads(PlantSettings(**frags["plant"]).scenario) == frags["plant"]["scenario"]
    assert Stimulus().step("valve.u2", 1.0).settings() == {"controller": {"stimulus": [{"input": "valve.u2", "shape": "step", "size": 1.0, "at_s": 0.0}]}}


def test_the_plant_profiles_merge_into_an_existing_scenario() -> None:
    existing = {
        "commands": [{"kind": "payload", "at_sim_time_s": 5.0, "payload_attached": True}],
        "channel_faults": [{"channel": "AI3", "kind": "offset", "offset_v": 0.5, "start_s": 1.0}],
        "stimulus": [{"input": "disturbance.link1", "shape": "step", "size": 3.0}],
    }
    frags = Stimulus().sine("disturbance.link2", 5.0, 4.0).settings(scenario=json.dumps(existing))
    merged = frags["plant"]["scenario"]
    assert merged["commands"] == existing["commands"] and merged["channel_faults"] == existing["channel_faults"]
    assert [p["input"] for p in merged["stimulus"]] == ["disturbance.link1", "disturbance.link2"]
    assert "controller" not in frags
    PlantSettings(**frags["plant"])
    commands = [{"kind": "seed", "at_sim_time_s": 1.0, "seed": 3}]
    assert Stimulus().settings(scenario=commands) == {"plant": {"scenario": {"commands": commands}}}


def test_a_bad_profile_is_refused_by_the_builder_in_one_line() -> None:
    with pytest.raises(ConfigError) as caught:
        Stimulus().step("valve.u1", 12.0).settings()
    assert str(caught.value) == "stimulus item 0: valve.u1 would reach 0 .. 12 V, outside its range -10 .. 10 V"
    with pytest.raises(ConfigError, match="scenario stimulus item 0: disturbance.link1 would reach"):
        Stimulus().sine("disturbance.link1", 150.0, 1.0).settings()


def test_yaml_profiles_with_paths_relative_to_the_file(tmp_path: Path) -> None:
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "push.csv").write_text("t,value\n0,0\n0.5,20\n1.0,0\n")
    spec = tmp_path / "stim.yaml"
    spec.write_text(
        "stimulus:\n"
        "  - {input: valve.u2, shape: prbs, amplitude: 0.3, bit_s: 0.02, seed: 7, at_s: 1}\n"
        "  - input: disturbance.link2\n"
        "    shape: playback\n"
        "    csv: profiles/push.csv\n"
        "    hold: zoh\n"
        "    at_s: 2\n"
    )
    stim = Stimulus.from_yaml(spec)
    assert len(stim) == 2
    frags = stim.settings()
    assert frags["plant"]["scenario"]["stimulus"][0]["csv"] == str(tmp_path / "profiles" / "push.csv")
    controller_plan, plant_plan = stim.plans()
    assert plant_plan.profiles[0].end == 3.0 and controller_plan.profiles[0].end is None
    spec.write_text("stimulus: {input: valve.u2}\n")
    with pytest.raises(ConfigError, match="a stimulus file is a list of profiles"):
        Stimulus.from_yaml(spec)
    spec.write_text("- [unclosed\n")
    with pytest.raises(ConfigError, match="is not YAML"):
        Stimulus.from_yaml(spec)
    with pytest.raises(ConfigError, match="cannot read"):
        Stimulus.from_yaml(tmp_path / "missing.yaml")
