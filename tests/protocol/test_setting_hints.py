"""One answer to a misspelt setting wherever it is given (protocol/setting_hints.py): the same
line from ``ralf-hil up --set``, a service's ``--set``, the environment, the pytest fixture and
a sweep spec; given before a program loads its modules, and nothing created."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from protocol import setting_names
from protocol.setting_hints import ANY, refuse_misspelt_settings, set_arguments, unknown_setting, variable
from protocol.settings import RETIRED, ControllerSettings, DspSettings, PlantSettings
from workbench.config_docs import SETTING_NAMES_PATH, setting_names_module

ROOT = Path(__file__).resolve().parents[2]
CONTROLLER_TYPO = "'oatf_mod' is not a setting of the controller; did you mean 'oatf_mode' or 'oatf'?"


def test_the_names_module_is_generated_from_the_models() -> None:
    assert (ROOT / SETTING_NAMES_PATH).read_text() == setting_names_module(), "regenerate it: python -m workbench.config_docs --names"
    assert setting_names.SERVICES == {
        "plant": tuple(PlantSettings.model_fields),
        "controller": tuple(ControllerSettings.model_fields),
        "dsp": tuple(DspSettings.model_fields),
    }
    assert setting_names.RETIRED == frozenset(RETIRED)


@pytest.mark.parametrize(
    ("name", "service", "line"),
    [
        ("oatf_mod", "controller", CONTROLLER_TYPO),
        ("RALF_OATF_MOD", "controller", CONTROLLER_TYPO),
        ("oatf_mode", "plant", "'oatf_mode' is not a setting of the plant: it belongs to the controller"),
        ("fft_width", "common", "'fft_width' is not a setting of every service: it belongs to the dsp"),
        ("batch_size", "plant", "'batch_size' is not a setting of the plant: it belongs to the controller and the dsp"),
        ("adc_bit", ANY, "'adc_bit' is not a setting of any service; did you mean 'adc_bits'?"),
        ("nosuch", "dsp", "'nosuch' is not a setting of the dsp (see ralf-dsp --help for the settings)"),
        ("oatf_mode", "controller", None),
        ("seed", ANY, None),
        ("record", "controller", None),  # retired: its own reason is given by protocol.settings.retired
    ],
)
def test_one_line(name: str, service: str, line: str | None) -> None:
    assert unknown_setting(name, service) == line


def test_the_environment_is_spelt_as_variables() -> None:
    assert unknown_setting("RALF_OATF_MOD", ANY, variable) == "RALF_OATF_MOD is not a setting of any service; did you mean RALF_OATF_MODE or RALF_OATF?"


def test_set_arguments_in_both_forms() -> None:
    assert set_arguments(["--set", "a=1", "--duration", "3", "--set=b=2", "--", "--set", "c=3"]) == ["a=1", "b=2"]


def test_the_early_refusal_is_one_line_per_name(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_:
        refuse_misspelt_settings("ralf-controller", "controller", ["--set", "oatf_mod=adaptive"], {"RALF_OATF_MODE": "adaptive", "RALF_SED": "3"})
    assert exit_.value.code == 2
    assert capsys.readouterr().err.splitlines() == [
        f"ralf-controller: --set 'oatf_mod=adaptive': {CONTROLLER_TYPO}",
        "ralf-controller: RALF_SED is not a setting of any service; did you mean RALF_SEED?",
    ]
    refuse_misspelt_settings("ralf-controller", "controller", ["--set", "oatf_mode=adaptive", "--set", "bad"], {"RALF_SEED": "3"})  # malformed: its parser says


def test_a_sweep_spec_and_the_fixture_give_the_same_line() -> None:
    from workbench.campaign.spec import SpecError, resolve
    from workbench.hil import RigSettingError, check_settings

    with pytest.raises(SpecError, match=CONTROLLER_TYPO.replace("?", r"\?")):
        resolve({"controller.oatf_mod": "adaptive"})
    with pytest.raises(SpecError, match="'oatf_mode' is not a setting of the plant: it belongs to the controller"):
        resolve({"plant.oatf_mode": "adaptive"})
    with pytest.raises(RigSettingError, match="'oatf_mode' is not a setting of the plant: it belongs to the controller"):
        check_settings({"plant": {"oatf_mode": "adaptive"}})


def test_the_service_parser_gives_the_same_line(capsys: pytest.CaptureFixture[str]) -> None:
    from service_kit.runtime import parse_service_args

    with pytest.raises(SystemExit) as exit_:
        parse_service_args("ralf-controller", "", ControllerSettings, ["--set", "oatf_mod=adaptive"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == f"ralf-controller: --set 'oatf_mod=adaptive': {CONTROLLER_TYPO}\n"


@pytest.mark.parametrize(
    ("argv", "env", "line"),
    [
        (["-m", "workbench", "up", "--set", "controller.oatf_mod=adaptive"], {}, f"ralf-hil up: --set 'controller.oatf_mod=adaptive': {CONTROLLER_TYPO}"),
        (
            ["-m", "workbench", "up"],
            {"RALF_OATF_MOD": "adaptive"},
            "ralf-hil up: RALF_OATF_MOD is not a setting of any service; did you mean RALF_OATF_MODE or RALF_OATF?",
        ),
        (["-m", "controller", "--set", "oatf_mod=adaptive"], {}, f"ralf-controller: --set 'oatf_mod=adaptive': {CONTROLLER_TYPO}"),
        (
            ["-m", "plant_emulator", "--set", "oatf_mode=adaptive"],
            {},
            "ralf-plant: --set 'oatf_mode=adaptive': 'oatf_mode' is not a setting of the plant: it belongs to the controller",
        ),
    ],
)
def test_programs_refuse_before_loading_their_modules_and_create_nothing(tmp_path: Path, argv: list[str], env: dict[str, str], line: str) -> None:
    """The refusal comes before numpy, zenoh or the rig's modules are imported (``-X importtime``
    lists every module the process loaded), and the temporary directory stays empty."""
    environ = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")} | env | {"TMPDIR": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-X", "importtime", *argv], capture_output=True, text=True, timeout=60, cwd=tmp_path, env=environ)
    loaded = {row.rsplit("|", 1)[-1].strip() for row in proc.stderr.splitlines() if row.startswith("import time:")}
    said = [row for row in proc.stderr.splitlines() if not row.startswith("import time:")]
    assert proc.returncode == 2 and said == [line], proc.stderr[-2000:]
    assert loaded.isdisjoint({"numpy", "zenoh", "pydantic", "workbench.cli", "protocol.settings"}), sorted(loaded)
    assert list(tmp_path.iterdir()) == []
