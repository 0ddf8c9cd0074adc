"""Stimulus profiles through whole rigs: what reaches the D/A and the record,
the plant's events, and the same bits in the co-simulation and the
one-process lockstep rig."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import scipy.signal

import workbench.cosim as cosim
from controller.record import load_record
from controller.service import RECORD_COLUMNS
from protocol.batch_codec import SampleBatch, decode_batch
from protocol.can_map import DAC12
from workbench.cosim import run_cosim
from workbench.stimulus import Stimulus

DSP = {"fft_width": 256}
STEP_V = 2.3


def _save(run: object, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    run.controller.save(str(path), run.result)  # type: ignore[attr-defined]
    return path


def test_a_valve_override_step_reaches_the_da_as_its_quantized_value(tmp_path: Path) -> None:
    stim = Stimulus().step("valve.u1", STEP_V, at_s=1.0, for_s=0.5).step("setpoint.phi2", 0.05, at_s=0.5, end_s=2.5)
    run = run_cosim(controller={"duration_s": 3.0, "tf_download_samples": 0, **stim.settings()["controller"]}, dsp=DSP)
    assert run.result.error is None
    c = run.controller.record.to_columns()
    assert list(c) == [*list(RECORD_COLUMNS)[:-1], "stim_phi1_rad", "stim_phi2_rad", "stim_u1_v", "stim_u2_v", "tick"]
    t = c["t_s"]
    window = (t >= 1.0 - 1e-9) & (t < 1.5 - 1e-9)
    assert window.sum() == 100
    code = round(STEP_V / DAC12.lsb_v)
    assert code * DAC12.lsb_v != STEP_V  # the step is not on the D/A's grid: the test sees the quantization
    assert np.all(c["u1_v"][window] == code * DAC12.lsb_v)
    assert np.all(c["stim_u1_v"][window] == STEP_V) and np.all(np.isnan(c["stim_u1_v"][~window]))
    assert np.any(c["u1_v"][~window] != code * DAC12.lsb_v)  # the PI drives the valve outside the window
    assert np.all(np.isnan(c["stim_u2_v"])) and np.all(c["stim_phi1_rad"] == 0.0)
    # the set-point offset is in the set-point the PI followed
    plain = run_cosim(controller={"duration_s": 3.0, "tf_download_samples": 0}, dsp=DSP).controller.record.to_columns()
    assert list(plain) == list(RECORD_COLUMNS)
    offset = (t >= 0.5 - 1e-9) & (t < 2.5 - 1e-9)
    np.testing.assert_allclose(c["phi_ref2"] - plain["phi_ref2"], np.where(offset, 0.05, 0.0), rtol=0, atol=1e-12)
    assert np.array_equal(c["phi_ref1"], plain["phi_ref1"])
    assert np.array_equal(c["stim_phi2_rad"], np.where(offset, 0.05, 0.0))
    # the profiles' starts and ends in the record's sidecar
    path = _save(run, tmp_path / "run")
    events = load_record(path).metadata["stimulus"]["events"]
    assert [(e["input"], e["event"], e["tick"]) for e in events] == [
        ("setpoint.phi2", "start", 100),
        ("valve.u1", "start", 200),
        ("valve.u1", "end", 300),
        ("setpoint.phi2", "end", 500),
    ]
    plain_path = _save(run_cosim(controller={"duration_s": 0.5, "tf_download_samples": 0}, dsp=DSP), tmp_path / "plain" / "run")
    assert "stimulus" not in json.loads(plain_path.with_suffix(".json").read_text())["metadata"]


def _npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.timeout(600)
def test_a_stimulated_cosim_equals_the_one_process_lockstep_run_bit_for_bit(tmp_path: Path) -> None:
    """As tests/rig/test_lockstep_determinism.py compares them, with profiles on both sides."""
    from workbench.composition import run_in_process

    stim = (
        Stimulus()
        .chirp("valve.u2", 1.0, 1.0, 8.0, 3.0, at_s=1.0)
        .prbs("setpoint.phi1", 0.01, 0.05, seed=4, at_s=0.5)
        .sine("disturbance.link2", 20.0, 4.0, at_s=2.0, for_s=2.0)
        .step("payload", 1.0, at_s=1.5, end_s=3.5)
    )
    frags = stim.settings()
    schedule = [  # scripted parameter changes (docs/calibration.md) at tick boundaries, on and off the tick grid
        {"name": "controller.kp1", "value": 12000.0, "at_s": 1.2},
        {"name": "controller.ki2", "value": 2000.0, "at_s": 2.5031},
        {"name": "controller.oatf_zeta", "value": 0.2, "at_s": 3.0},
    ]
    controller = {"duration_s": 5.0, "oatf_mode": "adaptive", "tf_download_samples": 500, "param_schedule": schedule, **frags["controller"]}
    records = []
    for name, runner in (("cosim", run_cosim), ("one", run_in_process)):
        record = tmp_path / name / "run"
        record.parent.mkdir(parents=True)
        run = runner(controller=dict(controller), dsp=dict(DSP), plant={"seed": 5, "truth_record": str(record), **frags["plant"]})
        assert run.result.error is None
        run.controller.save(str(record), run.result)
        records.append(record)
    a, b = records
    for name in ("run.npz", "run.tf.npz", "run.truth.npz"):
        x, y = _npz(a.parent / name), _npz(b.parent / name)
        assert x.keys() == y.keys(), name
        for key in x:
            assert np.array_equal(x[key], y[key], equal_nan=True), (name, key)
    ra, rb = load_record(a), load_record(b)
    assert ra.metadata["stimulus"] == rb.metadata["stimulus"]
    changes = [c for c in ra.metadata["result"]["config_changes"] if c["kind"] == "schedule"]
    assert changes == [c for c in rb.metadata["result"]["config_changes"] if c["kind"] == "schedule"]
    assert [(round(c["sim_time_s"] / 0.005), c["fields"]) for c in changes] == [(240, {"kp1": 12000.0}), (501, {"ki2": 2000.0}), (600, {"oatf_zeta": 0.2})]
    assert len(ra) == 1000 and np.isfinite(ra["stim_u2_v"]).sum() == 600
    truth = _npz(a.parent / "run.truth.npz")
    attached = truth["payload_attached"]
    t = truth["sim_time_s"]
    assert attached[(t > 1.6) & (t < 3.4)].all() and not attached[(t < 1.4) | (t > 3.6)].any()


def test_hil_rig_takes_the_fragments_and_the_plant_reports_each_profile(tmp_path: Path) -> None:
    from workbench.hil import HilRig

    stim = Stimulus().step("valve.u1", 1.0, at_s=0.5, for_s=0.25).step("disturbance.link1", 10.0, at_s=1.0, for_s=0.5)
    frags = stim.settings(scenario=[{"kind": "seed", "at_sim_time_s": 0.2, "seed": 9}])
    assert frags["plant"]["scenario"]["commands"] == [{"kind": "seed", "at_sim_time_s": 0.2, "seed": 9}]
    rig = HilRig(controller={"tf_download_samples": 0, **frags["controller"]}, plant_settings=frags["plant"], dsp_settings=dict(DSP))
    record = rig.run(2.0)
    assert record.error is None
    events = [(e.kind, round(e.sim_time_s, 3)) for e in record.events if e.kind.startswith("stimulus") or e.kind == "seed"]
    assert events == [("seed", 0.2), ("stimulus_start", 1.0), ("stimulus_end", 1.5)]
    on = (record.columns["t_s"] >= 0.5 - 1e-9) & (record.columns["t_s"] < 0.75 - 1e-9)
    assert np.all(record.columns["u1_v"][on] == round(1.0 / DAC12.lsb_v) * DAC12.lsb_v)
    assert math.isnan(record.columns["stim_u1_v"][0])


def test_the_dsp_batches_carry_the_valve_override_not_the_pi_command(monkeypatch: pytest.MonkeyPatch) -> None:
    """The identifier is fed what the D/A applied: while a valve profile is active, the override."""
    batches: list[SampleBatch] = []
    send = cosim.DirectDspPort.send_batch

    def spy(port: cosim.DirectDspPort, payload: bytes) -> None:
        batches.append(decode_batch(payload))
        send(port, payload)

    monkeypatch.setattr(cosim.DirectDspPort, "send_batch", spy)
    stim = Stimulus().chirp("valve.u2", 0.3, 1.0, 8.0, 2.0, at_s=0.5)
    run = run_cosim(controller={"duration_s": 3.0, "tf_download_samples": 0, **stim.settings()["controller"]}, dsp=DSP)
    assert run.result.error is None
    c = run.controller.record.to_columns()
    assert batches and batches[0].first_tick == 0
    inputs = np.concatenate([np.asarray(b.inputs, dtype=float) for b in batches], axis=1)  # (2, samples): valve 1, valve 2
    ticks = np.arange(inputs.shape[1])
    t = ticks * 0.005
    active = (t >= 0.5 - 1e-9) & (t < 2.5 - 1e-9)
    assert active.sum() == 400
    chirp = 0.3 * scipy.signal.chirp(t[active] - 0.5, 1.0, 2.0, 8.0)
    np.testing.assert_allclose(inputs[1, active], chirp, rtol=0, atol=DAC12.lsb_v / 2 + 1e-12)  # the chirp, through the D/A
    assert np.abs(inputs[1, active] - c["pi2_v"][ticks][active]).max() > 0.1  # not the PI's command
    np.testing.assert_array_equal(inputs[1, ~active], c["u2_v"][ticks][~active])  # the PI's, through the D/A, outside
    np.testing.assert_array_equal(inputs[0], c["u1_v"][ticks])
