"""A plant model that dies (the FMU's doStep returns Error at a set step,
the FMU's own fault_step/fault_kind parameters, not a mock) ends the run as
a lost plant does: the controller sees the plant's EMCY PLANT_MODEL_FAULT,
applies its plant-fault policy (valves to zero, the run's error, exit 3 of
the service) one tick after the fault, in co-simulation and in the
one-process lockstep rig alike, and the run's verdict is INVALID. A
discarded step (the model goes on) is counted and only degrades the run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from protocol.can_map import EmcyCode
from tests.plant.fmu.support import plant_settings, write_mapping
from workbench.verdict import judge

FAULT_STEP = 300
ERROR, DISCARD = 2, 1


def _summary(run: Any) -> dict[str, Any]:
    return {
        "controller": {"ticks": run.result.ticks},
        "health": {name: h.model_dump() for name, h in run.health.items()},
        "exit_codes": {"controller": 0 if run.result.error is None else 3},
        "failure": run.result.error or "",
    }


def _run(mode: str, fmu: Path, mapping: Path) -> Any:
    controller = {"duration_s": 3.0}
    if mode == "cosim":
        from workbench.cosim import run_cosim

        return run_cosim(controller=controller, plant=plant_settings(fmu, mapping))
    from workbench.composition import run_in_process

    return run_in_process(controller=controller, plant=plant_settings(fmu, mapping))


@pytest.mark.timeout(300)
@pytest.mark.parametrize("mode", ["cosim", "lockstep"])
def test_a_dead_plant_model_is_a_plant_fault_and_an_invalid_run(two_mode_fmu: Path, tmp_path: Path, mode: str) -> None:
    run = _run(mode, two_mode_fmu, write_mapping(tmp_path, parameters={"fault_step": FAULT_STEP, "fault_kind": ERROR}))
    assert run.result.error is not None and run.result.error.startswith("plant model dead: EMCY PLANT_MODEL_FAULT, cause 1")
    # The EMCY comes with the failed step's TPDO1; the next TPDO1 (the node's word on it) ends the run.
    assert FAULT_STEP < run.result.ticks <= FAULT_STEP + 3
    counters = run.health["controller"].counters
    assert counters["plant_model_faults"] == 1 and counters["plant_model_dead"] == 1
    assert any(e.code == EmcyCode.PLANT_MODEL_FAULT for e in run.controller.plant.emergencies)
    verdict = judge(_summary(run))
    assert verdict.level == "INVALID" and verdict.exit_code == 1
    assert verdict.reasons[0].startswith("plant model dead")


@pytest.mark.timeout(300)
def test_a_discarded_step_goes_on_and_degrades_the_run(two_mode_fmu: Path, tmp_path: Path) -> None:
    run = _run("cosim", two_mode_fmu, write_mapping(tmp_path, parameters={"fault_step": FAULT_STEP, "fault_kind": DISCARD}))
    assert run.result.error is None and run.result.ticks == 600
    assert run.health["controller"].counters["plant_model_faults"] == 1
    assert run.health["controller"].counters["plant_model_dead"] == 0
    verdict = judge(_summary(run))
    assert verdict.level == "DEGRADED" and verdict.exit_code == 0
    assert verdict.reasons == ("plant model steps discarded (outputs held): 1",)
