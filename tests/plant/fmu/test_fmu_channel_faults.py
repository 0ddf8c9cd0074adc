"""Channel faults with an FMU as the plant: the same seam as the built-in
arm's, so TPDO1 carries the fault of the FMU's mapped outputs."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.plant.fmu.support import EXAMPLE_MAPPING, plant_settings
from tests.plant.test_channel_faults import START, Run, active, quantize


def test_fmu_plant_tpdo1_carries_the_faulted_codes(two_mode_fmu: Path, tmp_path: Path) -> None:
    faults = [
        {"channel": "AI3", "kind": "short_ground", "start_s": START, "end_s": 0.6},
        {"channel": "AI4", "kind": "offset", "offset_v": 1.25, "start_s": START},
        {"channel": "AO1", "kind": "open", "start_s": START},
    ]
    run = Run(tmp_path, faults, plant=plant_settings(two_mode_fmu, EXAMPLE_MAPPING))
    t, true_v = run.t, run.true_v
    want = true_v.copy()
    want[active(t, START, 0.6), 2] = 0.0
    want[active(t, START, None), 3] += 1.25
    np.testing.assert_array_equal(run.codes, quantize(want)[0])
    assert (run.codes[active(t, START, 0.6), 2] == 0).all() and not (quantize(true_v)[0][:, 2] == 0).all()
    da_on = active(run.truth["channel_da_time_s"], START, None)
    assert (run.truth["channel_da_applied_v"][da_on, 0] == 0.0).all()
    np.testing.assert_array_equal(run.truth["channel_da_applied_v"][~da_on], run.truth["channel_da_commanded_v"][~da_on])
