"""A channel fault's size driven by a stimulus profile: what reaches TPDO1 and
the truth file, the checks before the run, and the same bits in the
co-simulation and the one-process lockstep rig."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, cast

import can
import cantools
import numpy as np
import numpy.typing as npt
import pytest
from mcap.reader import make_reader

from plant_emulator.channel_faults import ChannelFaultUnit
from protocol.can_map import ConverterScale
from protocol.errors import ConfigError
from protocol.scenario_setting import parse_channel_faults, parse_scenario_stimulus
from protocol.settings import PlantSettings, load_settings
from protocol.stimulus_inputs import describe_inputs, lookup
from workbench.cosim import run_cosim
from workbench.stimulus import Stimulus

DBC = cast(cantools.database.can.Database, cantools.database.load_file(str(Path(__file__).resolve().parents[2] / "protocol" / "ralf.dbc")))
TPDO1 = DBC.get_message_by_name("TPDO1_AnalogInputs16")
CONTROLLER = {"duration_s": 1.2, "tf_download_samples": 0, "batch_size": 20}
DSP = {"fft_width": 256, "emulated_latency_s": 0.05}
BITS = 12
LSB = 20.0 / 2**BITS
FAULT = {"channel": "AI3", "kind": "offset", "offset_v": 0.2, "start_s": 0.2, "end_s": 1.0}
"""An offset fault on the link-1 deflection input; its own size holds outside the profile's window."""
AT, OVER, FOR, TO = 0.4, 0.3, 0.4, 3.0
"""The profile: a ramp of the offset from 0 to TO over OVER s from AT, held until AT + FOR."""


def _scenario(profiles: list[dict[str, Any]], faults: list[dict[str, Any]] | None = None) -> str:
    return json.dumps({"channel_faults": [FAULT] if faults is None else faults, "stimulus": profiles})


def _ramp() -> dict[str, Any]:
    return {"input": "channel_fault.0.offset_v", "shape": "ramp", "to": TO, "over_s": OVER, "at_s": AT, "for_s": FOR}


def quantize(volts: npt.NDArray[np.float64]) -> npt.NDArray[np.int64]:
    """A 12-bit bipolar +-10 V converter: round half to even, clip at the end codes."""
    k = np.rint(np.clip(volts, -20.0, 20.0) / LSB)
    return np.clip(k, -(2 ** (BITS - 1)), 2 ** (BITS - 1) - 1).astype(np.int64)


def _offset(t: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    """offset(t) written with numpy: the fault's own 0.2 V in its window, the ramp while the profile is active, 0 outside the fault."""
    fault_on = (t + 1e-9 >= FAULT["start_s"]) & (t + 1e-9 < FAULT["end_s"])
    prof_on = (t + 1e-9 >= AT) & (t + 1e-9 < AT + FOR)
    tau = np.maximum(t - AT, 0.0)
    ramp = np.where(tau < OVER, TO * (tau / OVER), TO)
    return np.where(fault_on, np.where(prof_on, ramp, 0.2), 0.0)


def _events(path: Path) -> list[tuple[str, float]]:
    with open(path, "rb") as f:
        events = [json.loads(m.data) for _, channel, m in make_reader(f).iter_messages() if channel.topic.endswith("/plant/events")]
    return [(e["kind"], round(e["sim_time_s"], 6)) for e in events if e["kind"].startswith(("stimulus", "channel_fault"))]


def test_a_ramped_offset_reaches_tpdo1_as_the_quantized_offset_of_the_true_voltage(tmp_path: Path) -> None:
    run_cosim(
        controller=dict(CONTROLLER),
        dsp=dict(DSP),
        plant={"scenario": _scenario([_ramp()]), "truth_record": str(tmp_path / "run")},
        record=str(tmp_path / "run.mcap"),
        can_log=str(tmp_path / "run.asc"),
    )
    frames = [m for m in can.LogReader(str(tmp_path / "run.asc")) if m.arbitration_id == TPDO1.frame_id]
    words = np.array([[int(TPDO1.decode(bytes(m.data), scaling=False)[n]) for n in ("AI1", "AI2", "AI3", "AI4")] for m in frames], dtype=np.int64)
    with np.load(tmp_path / "run.truth.npz") as z:
        truth = {k: z[k] for k in z.files}
    t, true_v = truth["channel_ad_time_s"], truth["channel_ad_true_v"]
    assert words.shape == true_v.shape
    expected = true_v.copy()
    expected[:, 2] = true_v[:, 2] + _offset(t)
    np.testing.assert_allclose(truth["channel_ad_faulted_v"], expected, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(truth["channel_ad_faulted_v"][:, [0, 1, 3]], true_v[:, [0, 1, 3]])
    np.testing.assert_array_equal(words >> (16 - BITS), quantize(expected))
    ramping = (t > AT + 0.01) & (t < AT + OVER - 0.01)
    assert np.ptp(_offset(t)[ramping]) > 2.0  # the offset moved: the check compared a ramp, not a constant
    assert np.ptp((words >> (16 - BITS))[ramping, 2] - quantize(true_v[ramping, 2])) > 2.0 / LSB
    assert _events(tmp_path / "run.mcap") == [
        ("channel_fault", 0.2),
        ("stimulus_start", AT),
        ("stimulus_end", AT + FOR),
        ("channel_fault_cleared", 1.0),
    ]


def _npz(path: Path) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


@pytest.mark.timeout(600)
def test_a_fault_size_stimulus_in_cosim_equals_the_one_process_lockstep_run_bit_for_bit(tmp_path: Path) -> None:
    """As tests/stimulus/test_rig_stimulus.py compares them: a swept gain, a swept noise level and a ramped D/A offset."""
    from workbench.composition import run_in_process

    faults = [
        {"channel": "AI4", "kind": "gain", "factor": 1.0, "start_s": 0.5},
        {"channel": "AI1", "kind": "noise", "sigma_v": 0.01, "seed": 3, "start_s": 0.5},
        {"channel": "AO2", "kind": "offset", "offset_v": 0.0, "start_s": 1.0},
    ]
    stim = (
        Stimulus()
        .sine("channel_fault.0.factor", 0.5, 2.0, offset=1.0, at_s=1.0, for_s=2.0)
        .sine("channel_fault.1.sigma_v", 0.02, 3.0, offset=0.03, at_s=1.5, for_s=1.5)
        .ramp("channel_fault.2.offset_v", slope=0.5, at_s=1.5, for_s=2.0)
    )
    frags = stim.settings(scenario={"channel_faults": faults})
    duration = 4.0
    controller = {"duration_s": duration, "oatf_mode": "adaptive", "tf_download_samples": 400}
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
        if name == "run.truth.npz":  # the D/A updates of the run; the zeros each composition's node writes as it stops differ
            for z in (x, y):
                during = z["channel_da_time_s"] < duration - 1e-9
                for key in ("channel_da_time_s", "channel_da_commanded_v", "channel_da_applied_v"):
                    z[key] = z[key][during]
        for key in x:
            assert np.array_equal(x[key], y[key], equal_nan=True), (name, key)
    truth = _npz(a.parent / "run.truth.npz")
    t = truth["channel_ad_time_s"]
    on = (t > 1.0 + 1e-6) & (t < 3.0 - 1e-6)
    ratio = truth["channel_ad_faulted_v"][on, 3] / truth["channel_ad_true_v"][on, 3]
    np.testing.assert_allclose(ratio, 1.0 + 0.5 * np.sin(2 * np.pi * 2.0 * (t[on] - 1.0)), rtol=1e-9, atol=1e-9)
    da_t = truth["channel_da_time_s"]
    shift = truth["channel_da_applied_v"][:, 1] - truth["channel_da_commanded_v"][:, 1]
    ramp_on = (da_t > 1.5 + 1e-6) & (da_t < 3.5 - 1e-6)
    np.testing.assert_allclose(shift[ramp_on], 0.5 * (da_t[ramp_on] - 1.5), rtol=0, atol=1e-9)
    np.testing.assert_array_equal(shift[da_t > 3.5 + 1e-6], 0.0)  # the fault's own 0 V after the window


@pytest.mark.parametrize(
    ("profiles", "faults", "message"),
    [
        (
            [{"input": "channel_fault.1.offset_v", "shape": "step", "size": 1.0}],
            None,
            "stimulus item 0: channel_fault.1.offset_v: the scenario's channel_faults has faults 0..0",
        ),
        ([{"input": "channel_fault.0.offset_v", "shape": "step", "size": 1.0}], [], "channel_fault.0.offset_v: the scenario's channel_faults has no fault"),
        (
            [{"input": "channel_fault.0.factor", "shape": "step", "size": 2.0}],
            None,
            "stimulus item 0: channel_fault.0.factor (AI3 offset): a fault of kind 'offset' has no size 'factor'; its sizes a profile may drive: offset_v",
        ),
        (
            [{"input": "channel_fault.0.offset_v", "shape": "sine", "amplitude": 15.0, "f_hz": 1.0, "offset": 10.0}],
            None,
            "channel_fault.0.offset_v would reach -5 .. 25 V, outside its range -20 .. 20 V",
        ),
        (
            [{"input": "channel_fault.0.value_v", "shape": "step", "size": 12.0}],
            [{"channel": "AO1", "kind": "stuck"}],
            "channel_fault.0.value_v (AO1 stuck) would reach 0 .. 12 V, outside its range -10 .. 10 V",
        ),
        (
            [{"input": "channel_fault.0.bits", "shape": "step", "size": 2.0}],
            None,
            "channel_fault.0.bits: no channel fault size 'bits'; sizes: offset_v, factor",
        ),
    ],
)
def test_bad_fault_size_profiles_are_refused_in_one_line(profiles: list[dict[str, Any]], faults: list[dict[str, Any]] | None, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_scenario_stimulus(_scenario(profiles, faults))
    assert message in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(ConfigError) as loaded:  # the plant's settings refuse it where they load, before the node boots
        load_settings(PlantSettings, {"scenario": _scenario(profiles, faults)})
    assert message in str(loaded.value)


def test_the_sum_is_clipped_to_the_faults_range_and_the_size_returns_after_the_window() -> None:
    """Two profiles adding beyond a gain's +-10 read 10; the unit takes the plant's sizes as it is told."""
    from plant_emulator.service import PlantApplication

    text = _scenario(
        [
            {"input": "channel_fault.0.factor", "shape": "step", "size": 8.0, "at_s": 0.0, "for_s": 0.025},
            {"input": "channel_fault.0.factor", "shape": "step", "size": 6.0, "at_s": 0.01, "for_s": 0.01},
        ],
        [{"channel": "AI2", "kind": "gain", "factor": 0.5}],
    )
    app = PlantApplication(load_settings(PlantSettings, {"scenario": text, "clock": "lockstep"}))
    unit = app.channel_faults
    assert unit is not None
    factors = []
    for _ in range(6):  # 5 ms per SYNC: 0.005 .. 0.030 s
        app.on_sync(0)
        true_v = [1.0, 1.0, 1.0, 1.0]
        unit.convert(app.arm.time_s, true_v, ConverterScale(BITS))
        assert unit.last_conversion is not None
        factors.append(unit.last_conversion[2][1])
    assert factors == [8.0, 10.0, 10.0, 8.0, 0.5, 0.5]


def test_a_unit_without_sizes_set_reads_the_faults_own() -> None:
    unit = ChannelFaultUnit(parse_channel_faults(_scenario([])))
    codes, _ = unit.convert(0.5, [0.0, 0.0, 1.0, 0.0], ConverterScale(BITS))
    unit.set_size(0, "offset_v", 1.0)
    shifted, _ = unit.convert(0.5, [0.0, 0.0, 1.0, 0.0], ConverterScale(BITS))
    unit.set_size(0, "offset_v", None)
    again, _ = unit.convert(0.5, [0.0, 0.0, 1.0, 0.0], ConverterScale(BITS))
    assert codes[2] == int(np.rint(1.2 / LSB)) and shifted[2] == int(np.rint(2.0 / LSB)) and again == codes


def test_the_inputs_table_names_the_pattern_and_lookup_resolves_it() -> None:
    assert "| `channel_fault.<n>.<size>` | plant |" in describe_inputs()
    spec = lookup("channel_fault.3.sigma_v")
    assert spec is not None and (spec.side, spec.unit, spec.low, spec.high) == ("plant", "V", 0.0, 10.0)
    assert lookup("channel_fault.0.bits") is None and lookup("channel_fault.x.offset_v") is None
    assert Stimulus().step("channel_fault.0.offset_v", 1.0).side("plant")
