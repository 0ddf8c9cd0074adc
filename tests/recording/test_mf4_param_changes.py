"""A run's parameter changes in its MF4 export, the controller's and the
plant's: each ``ParamChanged`` event's parameter name (a value-to-text
channel) and value(s), with the table's unit, read back with asammdf against
the recording."""

from __future__ import annotations

from pathlib import Path

import can.io.mf4  # noqa: F401 -- before asammdf (workbench/recording/mf4.py says why)
import pytest

asammdf = pytest.importorskip("asammdf")

from workbench.hil import HilRig  # noqa: E402
from workbench.recording.mf4 import export_file  # noqa: E402
from workbench.recording.reader import Recording  # noqa: E402


def test_param_changes_carry_their_names_and_values(tmp_path: Path) -> None:
    rig = HilRig(controller={"duration_s": 1.0, "tf_download_samples": 0}, dsp_settings={"fft_width": 256}, workdir=tmp_path)
    rig.param.set("controller.kp1", 9000.0, at_s=0.25)
    rig.param.set("controller.kp2", 11000.0, at_s=0.5)
    rig.param.set("controller.ki2", 0.5, at_s=0.5)
    rig.param.set("plant.payload", 1.0, at_s=0.75)
    rec = rig.run()
    assert rec.error is None and rec.recording
    events = Recording.load(rec.recording).data("controller/param_changes")
    assert [e["fields"] for e in events] == [{"controller.kp1": 9000.0}, {"controller.kp2": 11000.0, "controller.ki2": 0.5}]
    out = tmp_path / "run.mf4"
    export_file(rec.recording, out)
    mdf = asammdf.MDF(out)
    try:
        name = mdf.get("controller.param_changes.name")
        assert [bytes(s).decode() for s in name.samples] == ["controller.kp1", "controller.kp2"]
        assert name.timestamps.tolist() == [e["sim_time_s"] for e in events]
        value = mdf.get("controller.param_changes.value")
        assert value.samples.tolist() == [9000.0, 11000.0] and value.unit == "mV/rad"
        kp2 = mdf.get("controller.param_changes.value.controller.kp2", ignore_invalidation_bits=True)
        assert kp2.invalidation_bits.tolist() == [True, False] and kp2.samples[1] == 11000.0 and kp2.unit == "mV/rad"
        ki2 = mdf.get("controller.param_changes.value.controller.ki2")  # the invalid sample hidden
        assert ki2.samples.tolist() == [0.5] and ki2.timestamps.tolist() == [events[1]["sim_time_s"]]
        (plant,) = Recording.load(rec.recording).data("plant/param_changes")
        payload = mdf.get("plant.param_changes.value.plant.payload")
        assert payload.samples.tolist() == [1.0] and payload.timestamps.tolist() == [plant["sim_time_s"]] == [0.75]
        assert [bytes(s).decode() for s in mdf.get("plant.param_changes.name").samples] == ["plant.payload"]
        assert mdf.get("plant.param_changes.tick").samples.tolist() == [150]
    finally:
        mdf.close()
