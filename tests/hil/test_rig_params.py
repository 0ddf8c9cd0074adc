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

from controller.record import load_record
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
    with pytest.raises(ConfigError, match=r"^controller\.input_stuck_samples = 2\.5 refused: not one of its whole steps$"):
        rig.param.set("controller.input_stuck_samples", 2.5)
    with pytest.raises(ConfigError, match=r"^controller\.dither_amplitude_v = 3\.0 refused: outside its limits 0 \.\. 2 V$"):
        rig.param.set("controller.dither_amplitude_v", 3.0)
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


def _first_difference(a: np.ndarray, b: np.ndarray) -> int:
    differ = np.flatnonzero(a != b)
    return int(differ[0]) if differ.size else -1


def test_a_scheduled_dither_amplitude_reaches_the_d_a_from_its_tick(tmp_path: Path) -> None:
    """The dither is added after the PI: from tick 201 the valve voltages differ from the same run
    without the change, the PI outputs of tick 201 (computed before the dither) do not."""
    runs = []
    for name, change in (("plain", False), ("muted", True)):
        rig = HilRig(controller={"duration_s": 1.5, "tf_download_samples": 0, "dither": "amplitude_v=0.05"}, dsp_settings=dict(DSP), workdir=tmp_path / name)
        if change:
            rig.param.set("controller.dither_amplitude_v", 0.0, at_s=1.0012)
        runs.append(rig.run())
    plain, muted = runs
    assert plain.error is None and muted.error is None
    ticks = muted.columns["tick"]
    at = int(np.flatnonzero(ticks == 201)[0])
    assert _first_difference(plain.columns["u1_v"], muted.columns["u1_v"]) == at
    assert _first_difference(plain.columns["pi1_v"], muted.columns["pi1_v"]) > at
    assert muted.param_changes == [{"sim_time_s": 201 * TS, "kind": "schedule", "fields": {"dither_amplitude_v": 0.0}, "who": "schedule"}]


def test_a_scheduled_input_limit_fires_its_monitor_from_its_tick() -> None:
    """A disagreement tolerance of 0.001 in from tick 201: ``input_disagree`` fires at that tick (policy
    count: the loop runs on unchanged); the run without the change never fires it."""
    from workbench.cosim import run_cosim

    controller = {"duration_s": 1.5, "tf_download_samples": 0, "input_monitors": "disagree=true", "policies": "input_disagree=count"}
    step = [{"name": "controller.input_disagree_in", "value": 0.001, "at_s": 1.0012}]
    plain, tight = (run_cosim(controller=dict(controller), dsp=dict(DSP)), run_cosim(controller={**controller, "param_schedule": step}, dsp=dict(DSP)))
    assert plain.result.error is None and tight.result.error is None
    assert plain.controller.inputs.events == [] and plain.controller.inputs.limits.disagree_in == 0.3
    (first, *_) = tight.controller.inputs.events
    assert first[:2] == (201, "input_disagree")
    assert tight.controller.inputs.limits.disagree_in == 0.001
    assert plain.controller.monitors.episodes["input_disagree"] == 0 < tight.controller.monitors.episodes["input_disagree"]
    assert np.array_equal(np.asarray(plain.controller.record.to_columns()["u1_v"]), np.asarray(tight.controller.record.to_columns()["u1_v"]))


@pytest.mark.timeout(300)
def test_cosim_and_the_one_process_lockstep_take_the_new_parameters_alike(tmp_path: Path) -> None:
    """A schedule of the dither's amplitude and the input monitors' limits: the co-simulation and the
    one-process lockstep rig keep the same records bit for bit, the monitors' firings included."""
    from workbench.composition import run_in_process
    from workbench.cosim import run_cosim

    schedule = [
        {"name": "controller.dither_amplitude_v", "value": 0.08, "at_s": 0.5},
        {"name": "controller.input_extension_rate_v_s", "value": 0.5, "at_s": 0.75},
        {"name": "controller.input_disagree_in", "value": 0.01, "at_s": 1.0},
    ]
    controller = {
        "duration_s": 1.5,
        "tf_download_samples": 0,
        "dither": "amplitude_v=0.02",
        "input_monitors": "rate=true,disagree=true",
        "policies": "input_rate=count,input_disagree=count",
        "param_schedule": schedule,
    }
    records, events = [], []
    for name, run_with in (("cosim", run_cosim), ("one", run_in_process)):
        run = run_with(controller=dict(controller))
        assert run.result.error is None
        path = tmp_path / name / "run"
        path.parent.mkdir(parents=True)
        run.controller.save(str(path), run.result)
        records.append(load_record(path))
        events.append(list(run.controller.inputs.events))
        assert [c.sim_time_s for c in run.controller.dsp.config_changes] == [0.5, 0.75, 1.0], name
    first, second = records
    assert len(first) == len(second) == 300
    for name in first.columns:
        assert np.array_equal(first[name], second[name], equal_nan=True), name
    assert events[0] == events[1]
    assert {m for _, m, _ in events[0]} == {"input_rate", "input_disagree"}  # the limits acted: the runs did work that could differ
