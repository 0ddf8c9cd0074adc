"""Scripted parameter changes through whole rigs (docs/calibration.md): a
``rig.param.set`` before the run is in the record from the first tick at or
after its time, listed in ``config_changes`` and on the recording's
``controller/param_changes``; a recording's settings run again give the same
bits; a bad change is one line before anything runs."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from protocol.errors import ConfigError
from workbench.hil import HilRig, RigRunError, RigSpec
from workbench.recording.reader import Recording

DSP = {"fft_width": 256}
TS = 0.005


def _pi_is_proportional(rec: object, kp_v_per_rad: float) -> np.ndarray:
    """Per tick: the joint 1 PI output is ``kp * (shaped set-point - angle)`` clipped (ki1 = 0)."""
    c = rec.columns  # type: ignore[attr-defined]
    expected = np.clip(kp_v_per_rad * (c["phi_shaped1"] - c["phi1"]), -10.0, 10.0)
    return np.isclose(c["pi1_v"], expected, rtol=1e-12, atol=1e-15)


def test_a_scheduled_gain_is_in_the_record_from_its_first_tick(tmp_path: Path) -> None:
    rig = HilRig(controller={"duration_s": 2.0, "tf_download_samples": 0}, dsp_settings=dict(DSP), workdir=tmp_path)
    rig.param.set("controller.kp1", 15000.0, at_s=1.0012)  # between ticks 200 and 201: from tick 201
    rig.param.set("controller.ki1", 0.0, at_s=1.0012)
    rec = rig.run()
    assert rec.error is None
    ticks = rec.columns["tick"]
    proportional = _pi_is_proportional(rec, 15.0)
    assert proportional[ticks >= 201].all()
    assert not proportional[(ticks < 201) & (ticks >= 150)].all()
    assert rec.param_changes == [{"sim_time_s": 201 * TS, "kind": "schedule", "fields": {"kp1": 15000.0, "ki1": 0.0}, "who": "schedule"}]
    assert rec.counters["param_changes_applied"] == 1 and rec.counters["param_sets_refused"] == 0
    # the recording's event topic holds the same change, by its full names, at its tick
    (event,) = Recording.load(rec.recording, only=("controller/param_changes",)).data("controller/param_changes")  # type: ignore[arg-type]
    assert (event["tick"], event["kind"], event["who"], event["fields"]) == (201, "schedule", "schedule", {"controller.kp1": 15000.0, "controller.ki1": 0.0})


def test_a_run_without_a_schedule_keeps_its_counters_and_records_no_change(tmp_path: Path) -> None:
    rec = HilRig(controller={"duration_s": 0.5, "tf_download_samples": 0}, dsp_settings=dict(DSP), workdir=tmp_path).run()
    assert not any(k.startswith("param_") for k in rec.counters)
    assert rec.param_changes == []
    assert "controller/param_changes" not in Recording.load(rec.recording).topics()  # type: ignore[arg-type]


def test_the_recordings_settings_run_again_give_the_same_bits(tmp_path: Path) -> None:
    """The schedule travels in the recording (its controller settings and its event topic):
    the co-simulation re-run from the recorded settings takes the same change at the same tick."""
    rig = HilRig(controller={"duration_s": 2.0, "tf_download_samples": 0, "oatf_mode": "fixed"}, dsp_settings=dict(DSP), workdir=tmp_path / "a")
    rig.param.set("controller.oatf_frequency_hz", 3.0, at_s=0.75)
    rig.param.set("controller.kp2", 12000.0, at_s=1.5)
    first = rig.run()
    recorded = Recording.load(first.recording)  # type: ignore[arg-type]
    settings = recorded.settings("controller")
    assert [(e["tick"], e["fields"]) for e in recorded.data("controller/param_changes")] == [
        (150, {"controller.oatf_frequency_hz": 3.0}),
        (300, {"controller.kp2": 12000.0}),
    ]
    again = HilRig(controller={"duration_s": 2.0, "tf_download_samples": 0, "oatf_mode": "fixed", "param_schedule": settings["param_schedule"]},
                   dsp_settings=dict(DSP), workdir=tmp_path / "b").run()  # fmt: skip
    for name, column in first.columns.items():
        assert np.array_equal(column, again.columns[name], equal_nan=True), name
    assert again.param_changes == first.param_changes
    oatf_hz, ticks = first.columns["oatf_hz"], first.columns["tick"]
    assert np.all(oatf_hz[ticks < 150] == 4.4) and np.all(oatf_hz[ticks >= 150] == 3.0)


def test_a_rig_spec_carries_the_schedule_frozen_and_picklable(tmp_path: Path) -> None:
    rig = HilRig()
    rig.param.set("controller.kp1", 9000.0, at_s=0.25)
    spec = RigSpec("s", controller={"duration_s": 0.5, "tf_download_samples": 0}, dsp=dict(DSP), params=rig.param.profiles())
    spec = pickle.loads(pickle.dumps(spec))
    rec = HilRig.from_spec(spec).run()
    assert rec.param_changes == [{"sim_time_s": 0.25, "kind": "schedule", "fields": {"kp1": 9000.0}, "who": "schedule"}]


def test_bad_changes_are_one_line_before_the_run() -> None:
    rig = HilRig(controller={"duration_s": 0.5})
    with pytest.raises(ConfigError, match=r"^controller\.kp1 = -1\.0 refused: outside its limits 0 \.\. 1e\+06 mV/rad$"):
        rig.param.set("controller.kp1", -1.0)
    with pytest.raises(ConfigError, match=r"^controller\.oatf_zeta = nan refused"):
        rig.param.set("controller.oatf_zeta", float("nan"))
    with pytest.raises(ConfigError, match=r"^no parameter 'controller\.kp3' \(known: controller\.kp1, "):
        rig.param.set("controller.kp3", 1.0)
    with pytest.raises(ConfigError, match=r"no board 'dsp' serves parameters \(have controller, plant\)"):
        rig.param.set("dsp.mass", 1.0)
    with pytest.raises(ConfigError, match=r"at_s must be a time at or after 0 s"):
        rig.param.set("controller.kp1", 1.0, at_s=-1.0)
    assert len(rig.param) == 0
    # the OATF's parameters in a run without an OATF: the controller refuses the schedule at its start
    rig.param.set("controller.oatf_frequency_hz", 3.0, at_s=0.1)
    with pytest.raises(RigRunError, match=r"param_schedule: controller\.oatf_frequency_hz at 0\.1 s: this run has no OATF \(oatf_mode off\)"):
        rig.run()


@pytest.mark.rig
@pytest.mark.timeout(300)
def test_three_processes_lockstep_take_the_schedule_as_the_cosimulation_does(tmp_path: Path) -> None:
    """The three-process rig in lockstep (the schedule travels in the controller's settings to its
    process) gives the co-simulation's columns bit for bit, the change at the same tick."""
    runs = []
    for name, processes, clock in (("three", True, "lockstep"), ("co", False, "cosim")):
        rig = HilRig(clock=clock, processes=processes, name=name, outputs=tmp_path, controller={"duration_s": 2.0}, dsp_settings=dict(DSP))  # type: ignore[arg-type]
        rig.param.set("controller.kp1", 15000.0, at_s=1.0)
        rig.param.set("controller.ki1", 0.0, at_s=1.0)
        try:
            runs.append(rig.run())
        finally:
            rig.close()
    three, co = runs
    assert three.error is None, three.error
    assert three.param_changes == co.param_changes == [{"sim_time_s": 1.0, "kind": "schedule", "fields": {"kp1": 15000.0, "ki1": 0.0}, "who": "schedule"}]
    for name, column in co.columns.items():
        assert np.array_equal(three.columns[name], column, equal_nan=True), name
    assert _pi_is_proportional(three, 15.0)[three.columns["tick"] >= 200].all()
