"""Structured settings are parsed within bounds (protocol/bounded_parse.py):
a value nested too deep, too long or holding too many values is one line,
never a parser's RecursionError; every file setting, the FMU mapping
included, must be a regular file."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.bounded_parse import MAX_DEPTH, TooLarge, check_nesting, load_json, load_yaml
from protocol.errors import ConfigError
from protocol.settings import ControllerSettings, PlantSettings, load_settings

DEEP = "[" * 90_000


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in list(os.environ):
        if name.startswith("RALF_"):
            monkeypatch.delenv(name)
    return monkeypatch


def _config_error(model: type, overrides: dict[str, str]) -> str:
    with pytest.raises(ConfigError) as info:
        load_settings(model, overrides)
    return " ".join(str(info.value).split())


def test_nesting_up_to_the_limit_parses_and_one_more_is_refused() -> None:
    ok = "[" * MAX_DEPTH + "]" * MAX_DEPTH
    assert load_json(ok, "x") is not None and load_yaml(ok, "x") is not None
    deeper = "[" * (MAX_DEPTH + 1) + "]" * (MAX_DEPTH + 1)
    for load in (load_json, load_yaml):
        with pytest.raises(TooLarge, match=f"deeper than {MAX_DEPTH} levels"):
            load(deeper, "x")
    check_nesting('["' + "[" * 100 + '"]', "x")  # brackets inside a string are text


def test_yaml_block_nesting_and_aliases_are_bounded() -> None:
    block = "".join(" " * i + "- \n" for i in range(0, 2 * (MAX_DEPTH + 2), 2)) + " " * (2 * (MAX_DEPTH + 2)) + "- 1\n"
    with pytest.raises(TooLarge, match="deeper than"):
        load_yaml(block, "x")
    laughs = ["a: &a [x, x, x, x, x, x, x, x, x, x]"] + [f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 10)}]" for i in range(8)]
    with pytest.raises(TooLarge, match="more than"):
        load_yaml("\n".join(laughs), "x")  # 10^9 values once expanded


def test_a_settings_text_past_the_size_limit_is_refused() -> None:
    with pytest.raises(TooLarge, match="characters long"):
        load_json("[" + "1," * 600_000 + "1]", "x")


@pytest.mark.parametrize(
    ("model", "name"),
    [(PlantSettings, "scenario"), (ControllerSettings, "policies"), (ControllerSettings, "timeouts")],
)
def test_a_deep_structured_setting_is_one_line(model: type, name: str) -> None:
    text = DEEP if name == "scenario" else "{" + '"a": ' * 1 + "[" * 5000 + "]" * 5000 + "}"
    message = _config_error(model, {name: text})
    assert "deeper than" in message and "Recursion" not in message, message


def test_a_deep_fault_scenario_is_one_line(tmp_path: Path) -> None:
    from service_kit.link_faults import ScenarioError, load_scenario, scenario_setting

    with pytest.raises(ScenarioError, match="deeper than"):
        scenario_setting('{"a": ' + DEEP)  # inline JSON
    for text in ('{"a": ' + DEEP, "a: " + DEEP):
        path = tmp_path / "faults.yaml"
        path.write_text(text)
        with pytest.raises(ScenarioError, match="deeper than"):
            load_scenario(path)


def test_ralf_scenario_of_90000_brackets_ends_the_plant_with_one_line(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")} | {"RALF_SCENARIO": DEEP}
    proc = subprocess.run([sys.executable, "-m", "plant_emulator"], capture_output=True, text=True, env=env, timeout=120, check=False, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and "RecursionError" not in proc.stderr
    assert "RALF_SCENARIO" in proc.stderr and "deeper than" in proc.stderr


def test_the_fmu_mapping_goes_through_the_regular_file_check(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    fifo = tmp_path / "map.fifo"
    os.mkfifo(fifo)
    fmu = tmp_path / "plant.fmu"
    fmu.write_bytes(b"PK")
    message = _config_error(PlantSettings, {"model": f"fmu:{fmu}", "fmu_mapping": str(fifo)})
    assert "is a FIFO, not a regular file" in message and "RALF_FMU_MAPPING" in message, message


@pytest.mark.parametrize(("target", "kind"), [("/dev/zero", "a character device"), ("fifo", "a FIFO"), ("dir", "a directory")])
def test_an_fmu_path_that_is_not_a_regular_file_says_what_it_is(clean_env: pytest.MonkeyPatch, tmp_path: Path, target: str, kind: str) -> None:
    mapping = tmp_path / "map.yaml"
    mapping.write_text("inputs: [a, b]\n")
    if target == "fifo":
        target = str(tmp_path / "plant.fmu")
        os.mkfifo(target)
    elif target == "dir":
        target = str(tmp_path)
    message = _config_error(PlantSettings, {"model": f"fmu:{target}", "fmu_mapping": str(mapping)})
    assert f"{target} is {kind}, not a regular file" in message and "no such" not in message.lower(), message


def test_a_deep_fmu_mapping_file_is_one_line(tmp_path: Path) -> None:
    from plant_emulator.fmu.mapping import load_mapping

    mapping = tmp_path / "map.yaml"
    mapping.write_text("inputs: " + DEEP)
    with pytest.raises(ConfigError, match="deeper than"):
        load_mapping(mapping)
    fifo = tmp_path / "map.fifo"
    os.mkfifo(fifo)
    with pytest.raises(ConfigError, match="is a FIFO"):
        load_mapping(fifo)  # never opened for reading: no writer would come


def test_a_deep_sweep_spec_is_one_line(tmp_path: Path) -> None:
    from workbench.campaign.spec import SpecError, load_spec

    for suffix, text in ((".yaml", "grid: " + DEEP), (".toml", "grid = " + DEEP)):
        spec = tmp_path / f"spec{suffix}"
        spec.write_text(text)
        with pytest.raises(SpecError, match="deeper than"):
            load_spec(spec)
