"""The FMU plant in real time (one process: plant, controller and DSP as
threads over a virtual CAN bus and zenoh): the FMU steps in whole sample
periods on the wall clock, every SYNC gets its TPDO1, and the plant's
health carries the FMU's step counters and times. No timing threshold:
only what a loaded host cannot change."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.plant.fmu.support import EXAMPLE_MAPPING, plant_settings


@pytest.mark.timeout(120)
def test_the_fmu_plant_runs_in_real_time(two_mode_fmu: Path) -> None:
    from workbench.composition import run_in_process

    run = run_in_process(
        controller={"duration_s": 3.0},
        plant=plant_settings(two_mode_fmu, EXAMPLE_MAPPING, health_period_s=0.5),
        common={"clock": "realtime"},
    )
    assert run.result.error is None and run.result.ticks > 0
    plant = run.health["plant"]
    c = plant.counters
    assert c["samples"] == c["syncs_applied"] > 0 and c["app_errors"] == 0
    # the plant's clock starts at SYNC 0: the steps cover the wall time from it to the last SYNC, one per
    # period, so they fall short of the SYNC count only by SYNC 0's own lateness (a few periods on a loaded host)
    assert c["fmu_steps"] >= 0.9 * c["syncs_applied"]
    assert c["fmu_step_errors"] == c["fmu_step_discards"] == c["fmu_non_finite_outputs"] == 0
    assert plant.latencies["fmu_step"].count == c["fmu_steps"]
    assert plant.latencies["sync_to_sample"].count == c["samples"]
