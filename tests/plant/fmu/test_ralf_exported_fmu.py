"""The built-in RALF arm exported as an FMI 3.0 co-simulation FMU with
pythonfmu3 (examples/fmu/ralf_arm_fmu.py) and run through the FMU path
gives the built-in path's co-simulation record bit for bit: every column
of the controller's record and every transfer-function snapshot (the
stated tolerance is zero). This also runs the FMI 3.0 side of the FMU
plant (fmi3SetFloat64 / fmi3DoStep / fmi3GetFloat64, an Int32 seed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

EXAMPLES = Path(__file__).resolve().parents[3] / "examples" / "fmu"
SCRIPT = EXAMPLES / "ralf_arm_fmu.py"
MAPPING = EXAMPLES / "ralf_arm.yaml"
CONTROLLER = {"duration_s": 12.0, "oatf_mode": "adaptive", "tf_download_samples": 500}
DSP = {"fft_width": 512}


@pytest.fixture(scope="module")
def ralf_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from pythonfmu3.builder import FmuBuilder

    return Path(FmuBuilder.build_FMU(SCRIPT, dest=tmp_path_factory.mktemp("ralf_fmu")))


@pytest.mark.timeout(300)
def test_the_exported_arm_gives_the_built_in_record_bit_for_bit(ralf_fmu: Path, tmp_path: Path) -> None:
    from controller.record import load_record
    from workbench.cosim import run_cosim

    runs = {}
    for name, plant in (("built-in", {}), ("fmu", {"model": f"fmu:{ralf_fmu}", "fmu_mapping": str(MAPPING)})):
        run = run_cosim(controller=dict(CONTROLLER), dsp=dict(DSP), plant={"seed": 3, **plant})
        assert run.result.error is None
        path = tmp_path / name / "run"
        path.parent.mkdir()
        run.controller.save(str(path), run.result)
        runs[name] = (run, path)
    fmu_run = runs["fmu"][0]
    assert fmu_run.health["plant"].counters["fmu_steps"] == 2400
    assert fmu_run.health["plant"].counters["fmu_step_errors"] == 0
    a, b = (load_record(runs[n][1]) for n in ("built-in", "fmu"))
    assert len(a) == len(b) == 2400 and a.columns.keys() == b.columns.keys()
    for column in a.columns:
        assert np.array_equal(a[column], b[column], equal_nan=True), column
    assert np.isfinite(a["f_id_hz"]).any() and np.ptp(a["ai3_word"]) > 100  # identification and motion: a record worth comparing
    tf_a, tf_b = np.load(str(runs["built-in"][1]) + ".tf.npz"), np.load(str(runs["fmu"][1]) + ".tf.npz")
    assert tf_a.files == tf_b.files
    for key in tf_a.files:
        assert np.array_equal(tf_a[key], tf_b[key]), key
