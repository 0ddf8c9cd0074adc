"""Bad stimulus profiles are refused before a run, in one line that names the problem."""

from __future__ import annotations

from pathlib import Path

import pytest

from protocol.errors import ConfigError
from protocol.settings import ControllerSettings, PlantSettings
from protocol.stimulus import parse_stimulus
from workbench.cosim import run_cosim

BAD = [
    ({"input": "valve.u3", "shape": "step", "size": 1.0}, "no stimulus input 'valve.u3'; inputs: setpoint.phi1, setpoint.phi2, valve.u1"),
    ({"input": "valve.u1", "shape": "step", "size": 10.5}, "valve.u1 would reach 0 .. 10.5 V, outside its range -10 .. 10 V"),
    ({"input": "setpoint.phi2", "shape": "sine", "amplitude": 0.15, "f_hz": 1.0, "offset": 0.1}, "outside its range -0.2 .. 0.2 rad"),
    ({"input": "valve.u1", "shape": "step", "size": 1.0, "at_s": 3.0, "end_s": 2.0}, "end_s 2 is not after at_s 3"),
    ({"input": "valve.u1", "shape": "ramp", "slope": 1.0}, "a ramp by slope needs its end"),
    ({"input": "valve.u1", "shape": "ramp", "slope": 1.0, "for_s": 20.0}, "would reach 0 .. 20 V"),
    ({"input": "valve.u1", "shape": "step", "size": 1.0, "for_s": 1.0, "end_s": 2.0}, "give for_s or end_s, not both"),
    ({"input": "valve.u1", "shape": "square", "size": 1.0}, "'square'"),
    ({"input": "valve.u1", "size": 1.0}, "shape missing"),
    ({"input": "valve.u1", "shape": "step", "size": 1.0, "gain": 2}, "gain: Extra inputs are not permitted"),
    ({"input": "payload", "shape": "step", "size": 1.0}, "payload is a plant input; the controller's inputs: setpoint.phi1"),
    ({"input": "valve.u1", "shape": "playback", "csv": "/nonexistent/p.csv"}, "cannot read /nonexistent/p.csv"),
    ({"input": "valve.u1", "shape": "prbs", "amplitude": 1.0, "bit_s": 0.0}, "bit_s: Input should be greater than 0"),
]


@pytest.mark.parametrize(("item", "message"), BAD)
def test_a_bad_profile_is_refused_in_one_line(item: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as caught:
        parse_stimulus([item], "controller")
    text = str(caught.value)
    assert "\n" not in text and text.startswith("stimulus item 0: ") and message in text


def test_playback_files_are_checked(tmp_path: Path) -> None:
    csv = tmp_path / "p.csv"
    csv.write_text("time,volts\n0,1\n1,2\n")
    with pytest.raises(ConfigError, match="has no columns 't' and 'value'; it has time, volts"):
        parse_stimulus([{"input": "valve.u1", "shape": "playback", "csv": str(csv)}], "controller")
    csv.write_text("t,value\n0,1\n1,12\n")
    with pytest.raises(ConfigError, match="would reach 0 .. 12 V"):
        parse_stimulus([{"input": "valve.u1", "shape": "playback", "csv": str(csv)}], "controller")
    csv.write_text("t,value\n1,1\n0,2\n")
    with pytest.raises(ConfigError, match="times must not decrease"):
        parse_stimulus([{"input": "valve.u1", "shape": "playback", "csv": str(csv)}], "controller")


def test_the_settings_refuse_them_at_load_for_each_side() -> None:
    with pytest.raises(ValueError, match="no stimulus input 'phi1'"):
        ControllerSettings(stimulus=[{"input": "phi1", "shape": "step", "size": 0.1}])
    with pytest.raises(ValueError, match="valve.u1 is a controller input; the plant's inputs: payload, disturbance.link1, disturbance.link2"):
        PlantSettings(scenario={"stimulus": [{"input": "valve.u1", "shape": "step", "size": 1.0}]})
    with pytest.raises(ValueError, match=r"disturbance.link1 would reach -150 .. 0 N, outside its range -100 .. 100 N"):
        PlantSettings(scenario={"stimulus": [{"input": "disturbance.link1", "shape": "step", "size": -150.0}]})
    with pytest.raises(ValueError, match="has no section 'stimuli'"):
        PlantSettings(scenario={"stimuli": []})
    assert ControllerSettings().stimulus == "" and PlantSettings(scenario={"stimulus": []}).scenario


def test_a_cosim_with_a_bad_stimulus_is_refused_before_it_runs() -> None:
    with pytest.raises(ConfigError, match="(?s)controller: .*RALF_STIMULUS: .*item 0: end_s 1 is not after at_s 2"):
        run_cosim(controller={"duration_s": 1.0, "stimulus": [{"input": "valve.u1", "shape": "step", "size": 1.0, "at_s": 2.0, "end_s": 1.0}]})


def test_a_rig_with_a_bad_stimulus_is_refused_in_one_line() -> None:
    from workbench.hil import HilRig, RigSettingError

    with pytest.raises(RigSettingError) as caught:
        HilRig(plant_settings={"scenario": {"stimulus": [{"input": "disturbance.link9", "shape": "step", "size": 1.0}]}})
    assert "\n" not in str(caught.value) and "no stimulus input 'disturbance.link9'" in str(caught.value)


def test_a_plant_model_without_the_input_is_refused_before_the_run() -> None:
    from plant_emulator.service import PlantApplication

    class NoForces:
        """A plant model with no link forces and no payload (as an FMU maps none)."""

    settings = PlantSettings(scenario={"stimulus": [{"input": "disturbance.link2", "shape": "step", "size": 5.0}]})
    with pytest.raises(ConfigError) as caught:
        PlantApplication(settings, arm=NoForces())  # type: ignore[arg-type]
    assert str(caught.value) == "stimulus on disturbance.link2: the plant model NoForces maps no such input (the built-in arm has it)"
