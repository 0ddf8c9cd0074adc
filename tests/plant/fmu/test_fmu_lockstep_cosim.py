"""With an FMU as the plant, lockstep stays a co-simulation master: two
co-simulations with the same FMU and seed give bit-identical run records,
equal to the one-process lockstep rig's (plant, controller and DSP as
threads over a virtual CAN bus and zenoh), and another seed (the FMU's
noise, through the mapping's seed_variable) gives another record."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from controller.record import load_record
from tests.plant.fmu.support import EXAMPLE_MAPPING, plant_settings

CONTROLLER = {"duration_s": 8.0, "oatf_mode": "adaptive", "tf_download_samples": 500}
DSP = {"fft_width": 512}


def _save(run: Any, path: Path) -> Path:
    assert run.result.error is None
    path.parent.mkdir(parents=True, exist_ok=True)
    run.controller.save(str(path), run.result)
    return path


def _cosim(fmu: Path, path: Path, seed: int) -> Path:
    from workbench.cosim import run_cosim

    return _save(run_cosim(controller=dict(CONTROLLER), dsp=dict(DSP), plant=plant_settings(fmu, EXAMPLE_MAPPING, seed=seed)), path)


def _one_process(fmu: Path, path: Path, seed: int) -> Path:
    from workbench.composition import run_in_process

    return _save(run_in_process(controller=dict(CONTROLLER), dsp=dict(DSP), plant=plant_settings(fmu, EXAMPLE_MAPPING, seed=seed)), path)


def _same(a: Path, b: Path) -> None:
    first, second = load_record(a), load_record(b)
    assert len(first) == len(second) == 1600
    assert first.columns.keys() == second.columns.keys()
    for name in first.columns:
        assert np.array_equal(first[name], second[name], equal_nan=True), name
    tf_a, tf_b = np.load(str(a) + ".tf.npz"), np.load(str(b) + ".tf.npz")
    assert tf_a.files == tf_b.files
    for key in tf_a.files:
        assert np.array_equal(tf_a[key], tf_b[key]), key


@pytest.mark.timeout(300)
def test_fmu_cosim_is_repeatable_and_equals_the_lockstep_rig(two_mode_fmu: Path, tmp_path: Path) -> None:
    a = _cosim(two_mode_fmu, tmp_path / "a" / "run", seed=4)
    _same(a, _cosim(two_mode_fmu, tmp_path / "b" / "run", seed=4))
    _same(a, _one_process(two_mode_fmu, tmp_path / "lockstep" / "run", seed=4))
    record = load_record(a)
    assert np.isfinite(record["f_id_hz"]).any()  # the DSP identified something: the runs did work that could differ
    assert np.ptp(record["ext1_in"]) > 1.0  # the FMU's cylinder followed the loop
    other = load_record(_cosim(two_mode_fmu, tmp_path / "c" / "run", seed=5))
    assert not np.array_equal(record["defl1_in"], other["defl1_in"])
