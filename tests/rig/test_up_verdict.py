"""ralf-hil up's verdict, deterministic (co-simulation, faults injected):
interrupts dropped by a link-fault scenario make the run DEGRADED, shown in
the table ("interrupts lost", "what went wrong", "run verdict") and in
--json beside the keys consumers read, exit 0; a plant model dead after an
Error step is a plant fault of the controller (exit 3) and an INVALID run,
exit 1; a clean run is PASS."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.plant.fmu.support import write_mapping
from workbench.cli import main


@pytest.fixture(scope="module")
def two_mode_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from plant_emulator.fmu.build import EXAMPLE_SOURCE, build_c_fmu

    return build_c_fmu(EXAMPLE_SOURCE, tmp_path_factory.mktemp("fmu") / "two_mode_plant.fmu")


DROPS = json.dumps({"name": "drops", "faults": [{"link": "zenoh", "kinds": ["interrupt"], "start_s": 2.0, "stop_s": 2.1, "drop": 1.0}]})


def _up(tmp_path: Path, capfd: pytest.CaptureFixture[str], *sets: str) -> tuple[int, dict, str]:
    out = tmp_path / "summary.json"
    code = main(["up", "--clock", "cosim", "--duration", "5", "--json", str(out), *[a for s in sets for a in ("--set", s)]])
    return code, json.loads(out.read_text()), capfd.readouterr().out


def test_a_clean_run_passes(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    code, summary, table = _up(tmp_path, capfd)
    assert code == 0 and summary["verdict"]["verdict"] == "PASS" and summary["verdict"]["reasons"] == []
    assert summary["verdict"]["findings"]["control_ticks"] == 1000
    assert summary["log_warnings"] == {"controller": 0, "plant": 0, "dsp": 0}
    assert "run verdict" in table and "PASS (exit 0" in table
    assert "controller 0 / 0, plant 0 / 0, dsp 0 / 0" in table


def test_dropped_interrupts_degrade_the_run_and_are_shown(tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    code, summary, table = _up(tmp_path, capfd, f"controller.fault_scenario={DROPS}")
    lost = summary["health"]["controller"]["counters"]["interrupts_lost"]
    assert lost > 0 and summary["verdict"]["findings"]["interrupts_lost"] == lost
    assert summary["verdict"]["verdict"] == "DEGRADED" and code == 0, summary["verdict"]
    assert f"interrupts lost (never came): {lost}" in summary["verdict"]["reasons"]
    assert summary["exit_codes"] == {"controller": 0} and summary["controller"]["ticks"] == 1000  # the old keys stay
    for row in ("interrupts lost", "what went wrong", "DEGRADED (exit 0"):
        assert row in table


@pytest.mark.timeout(300)
def test_a_dead_plant_model_ends_the_run_as_a_plant_fault_and_makes_it_invalid(two_mode_fmu: Path, tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    mapping = write_mapping(tmp_path, parameters={"fault_step": 200, "fault_kind": 2})
    code, summary, table = _up(tmp_path, capfd, f"plant.model=fmu:{two_mode_fmu}", f"plant.fmu_mapping={mapping}")
    assert code == 1 and summary["exit_codes"] == {"controller": 3}
    assert summary["verdict"]["verdict"] == "INVALID" and summary["verdict"]["findings"]["plant_model_dead"] is True
    assert summary["verdict"]["reasons"][0].startswith("plant model dead (FMU doStep at 1.000 s returned error")
    assert summary["failure"].startswith("plant model dead: EMCY PLANT_MODEL_FAULT")
    assert 200 < summary["controller"]["ticks"] <= 203
    assert summary["log_warnings"]["plant"] >= 1 and summary["log_errors"]["controller"] >= 1  # the FMU's fault line, the plant fault line
    assert "INVALID (exit 1" in table
