"""Bad FMUs and bad mappings are refused by ``ralf-hil up`` before the rig
starts: one line on stderr naming the file and the variable, exit 2, no
service, no rig lock, no extracted files left behind."""

from __future__ import annotations

import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from plant_emulator.fmu.build import EXAMPLE_SOURCE
from tests.plant.fmu.support import EXAMPLE_MAPPING, write_mapping

DESCRIPTION = (EXAMPLE_SOURCE / "modelDescription.xml").read_text()


def _rezip(src: Path, dest: Path, description: str | None = None, drop_binaries: bool = False) -> Path:
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dest, "w") as zout:
        for item in zin.infolist():
            if drop_binaries and item.filename.startswith("binaries/"):
                continue
            data = description.encode() if description is not None and item.filename == "modelDescription.xml" else zin.read(item)
            zout.writestr(item, data)
    return dest


FMI1 = """<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="1.0" modelName="old" modelIdentifier="old" guid="{0}" numberOfContinuousStates="0" numberOfEventIndicators="0">
  <ModelVariables>
    <ScalarVariable name="u1" valueReference="0" causality="input"><Real start="0"/></ScalarVariable>
  </ModelVariables>
  <Implementation><CoSimulation_StandAlone><Capabilities/></CoSimulation_StandAlone></Implementation>
</fmiModelDescription>
"""


@pytest.fixture
def isolated_tmp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """Temporary files (FMPy's extraction) go to a fresh directory, checked empty afterwards."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    yield scratch
    assert list(scratch.iterdir()) == []  # nothing extracted was left behind


def _cases(fmu: Path, tmp: Path) -> list[tuple[str, Path, Path, list[str], tuple[str, ...]]]:
    """(name, fmu, mapping, extra --set items, what the line must name)."""
    corrupt = tmp / "corrupt.fmu"
    corrupt.write_bytes(b"PK\x03\x04 not really a zip" * 10)
    cs = DESCRIPTION[DESCRIPTION.index("<CoSimulation") : DESCRIPTION.index("/>", DESCRIPTION.index("<CoSimulation")) + 2]
    me_only = _rezip(fmu, tmp / "me_only.fmu", DESCRIPTION.replace(cs, '<ModelExchange modelIdentifier="two_mode_plant"/>'))
    fmi1 = _rezip(fmu, tmp / "fmi1.fmu", FMI1)
    fmi9 = _rezip(fmu, tmp / "fmi9.fmu", DESCRIPTION.replace('fmiVersion="2.0"', 'fmiVersion="9.0"'))
    no_binary = _rezip(fmu, tmp / "no_binary.fmu", drop_binaries=True)
    good = EXAMPLE_MAPPING
    return [
        ("missing file", tmp / "nowhere.fmu", good, [], ("nowhere.fmu", "no such")),
        ("corrupt file", corrupt, good, [], ("corrupt.fmu", "not an FMU")),
        ("model exchange only", me_only, good, [], ("me_only.fmu", "model exchange only")),
        ("FMI 1.0", fmi1, good, [], ("fmi1.fmu", "FMI 1.0")),
        ("unknown FMI version", fmi9, good, [], ("fmi9.fmu",)),
        ("no binary for this platform", no_binary, good, [], ("no_binary.fmu", "binary")),
        ("missing variable", fmu, write_mapping(tmp, "m1.yaml", inputs=["u1", "valve_two"]), [], ("two_mode_plant.fmu", "'valve_two'")),
        ("output mapped as input", fmu, write_mapping(tmp, "m2.yaml", inputs=["u1", "x2"]), [], ("two_mode_plant.fmu", "'x2'", "causality 'output'")),
        ("input mapped as output", fmu, write_mapping(tmp, "m3.yaml", outputs=[{"variable": "u1"}] * 4), [], ("'u1'", "causality 'input'")),
        ("wrong type", fmu, write_mapping(tmp, "m4.yaml", seed_variable="f_a0"), [], ("'f_a0'", "is Real", "Integer")),
        ("wrong value type", fmu, write_mapping(tmp, "m5.yaml", parameters={"fault_step": 1.5}), [], ("'fault_step'", "1.5")),
        ("unknown parameter", fmu, write_mapping(tmp, "m6.yaml", parameters={"stiffness": 3.0}), [], ("'stiffness'",)),
        ("step size refused", fmu, good, ["plant.sample_rate_hz=300"], ("two_mode_plant.fmu", "refuses a step of 3.33333 ms")),
        ("mapping not found", fmu, tmp / "nomap.yaml", [], ("nomap.yaml",)),
        ("mapping incomplete", fmu, _write(tmp / "m7.yaml", "inputs: [u1, u2]\n"), [], ("m7.yaml", "outputs")),
        ("mapping not YAML", fmu, _write(tmp / "m8.yaml", "inputs: [u1, u2\n"), [], ("m8.yaml", "not YAML")),
    ]


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


@pytest.mark.parametrize("clock", ["cosim", "lockstep"])
def test_bad_fmus_are_refused_in_one_line_before_anything_starts(
    clock: str, two_mode_fmu: Path, tmp_path: Path, isolated_tmp: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import workbench.cli as cli

    def must_not_start(*args: object, **kwargs: object) -> None:
        raise AssertionError("the rig started")

    for name in ("acquire_rig_lock", "supervise", "provision_access", "_up_cosim"):
        monkeypatch.setattr(cli, name, must_not_start)
    cases = _cases(two_mode_fmu, tmp_path)
    for name, fmu, mapping, extra, needles in cases:
        sets = [f"plant.model=fmu:{fmu}", f"plant.fmu_mapping={mapping}", *extra]
        with pytest.raises(SystemExit) as exc:
            cli.main(["up", "--clock", clock, "--duration", "1", "--rig-id", "refuse", *[a for s in sets for a in ("--set", s)]])
        assert exc.value.code == 2, name
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert len(lines) == 1, (name, err)
        assert lines[0].startswith("ralf-hil up: plant refused: "), (name, err)
        for needle in needles:
            assert needle in lines[0], (name, needle, lines[0])
        assert "Traceback" not in err


def test_the_cosim_itself_refuses_a_bad_fmu_with_a_config_error(two_mode_fmu: Path, tmp_path: Path, isolated_tmp: Path) -> None:
    """Without the launcher's check, run_cosim refuses before anything runs (ConfigError)."""
    from protocol.errors import ConfigError
    from workbench.cosim import run_cosim

    mapping = write_mapping(tmp_path, inputs=["u1", "nope"])
    with pytest.raises(ConfigError, match="no variable 'nope'"):
        run_cosim(controller={"duration_s": 1.0}, plant={"model": f"fmu:{two_mode_fmu}", "fmu_mapping": str(mapping)})


def test_the_plant_service_refuses_a_bad_fmu_with_exit_2(two_mode_fmu: Path, tmp_path: Path, isolated_tmp: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``ralf-plant`` on its own: exit 2 and one logged line, before its CAN bus opens."""
    from plant_emulator.__main__ import main

    mapping = write_mapping(tmp_path, inputs=["u1", "nope"])
    code = main(["--set", f"model=fmu:{two_mode_fmu}", "--set", f"fmu_mapping={mapping}", "--set", "can_interface=virtual"])
    assert code == 2
    errors = [r.getMessage() for r in caplog.records if r.levelname == "ERROR"]
    assert len(errors) == 1 and "no variable 'nope'" in errors[0] and "\n" not in errors[0]
