"""Faults on the plant node's channels, checked against references.

Each co-simulated run takes its TPDO1 (and RPDO1) frames from the bus
(python-can's log of the run, decoded with cantools and protocol/ralf.dbc)
and the true A/D voltages from the plant's truth file; the expected codes
are the fault's function applied to the true voltages and quantized with
numpy, both written here independently of plant_emulator.channel_faults.
"""

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
from plant_emulator.service import PlantApplication
from protocol.can_map import ConverterScale
from protocol.channel_faults import FaultSchedule
from protocol.errors import ConfigError
from protocol.scenario_setting import parse_channel_faults
from protocol.settings import PlantSettings, load_settings
from workbench.cosim import run_cosim

DBC = cast(cantools.database.can.Database, cantools.database.load_file(str(Path(__file__).resolve().parents[2] / "protocol" / "ralf.dbc")))
TPDO1 = DBC.get_message_by_name("TPDO1_AnalogInputs16")
RPDO1 = DBC.get_message_by_name("RPDO1_AnalogOutputs16")
CONTROLLER = {"duration_s": 1.2, "tf_download_samples": 0, "batch_size": 20}
DSP = {"fft_width": 256, "emulated_latency_s": 0.05}
BITS = 12
LSB = 20.0 / 2**BITS
START, END = 0.3, 0.9
MOVING = {"dither": "amplitude_v=0.5"}
"""The valves dithered, so a fault on them has something to act on."""


class Run:
    """One faulted co-simulation: the frames on the bus and the truth file."""

    def __init__(self, tmp: Path, faults: list[dict[str, Any]], controller: dict[str, Any] | None = None, plant: dict[str, Any] | None = None) -> None:
        scenario = json.dumps({"commands": [], "channel_faults": faults})
        run_cosim(
            controller={**CONTROLLER, **(controller or {})},
            dsp=dict(DSP),
            plant={"scenario": scenario, "truth_record": str(tmp / "run"), **(plant or {})},
            record=str(tmp / "run.mcap"),
            can_log=str(tmp / "run.asc"),
        )
        frames = list(can.LogReader(str(tmp / "run.asc")))
        self.tpdo = np.array([_raw(TPDO1, m.data, ("AI1", "AI2", "AI3", "AI4")) for m in frames if m.arbitration_id == TPDO1.frame_id], dtype=np.int64)
        self.rpdo = np.array([_raw(RPDO1, m.data, ("AO1", "AO2")) for m in frames if m.arbitration_id == RPDO1.frame_id], dtype=np.int64)
        with np.load(tmp / "run.truth.npz") as z:
            self.truth = {k: z[k] for k in z.files}
        self.t = self.truth["channel_ad_time_s"]
        self.true_v = self.truth["channel_ad_true_v"]

    @property
    def codes(self) -> npt.NDArray[np.int64]:
        """TPDO1's 12-bit codes, as the bus carried them (left-justified words >> 4)."""
        return self.tpdo >> (16 - BITS)


def _raw(message: Any, data: bytes | bytearray, names: tuple[str, ...]) -> list[int]:
    decoded = message.decode(bytes(data), scaling=False)
    return [int(decoded[n]) for n in names]


def quantize(volts: npt.NDArray[np.float64]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.bool_]]:
    """A 12-bit bipolar +-10 V converter: round half to even, clip at the end codes, flag what was clipped."""
    k = np.rint(np.clip(volts, -20.0, 20.0) / LSB)
    lo, hi = -(2 ** (BITS - 1)), 2 ** (BITS - 1) - 1
    return np.clip(k, lo, hi).astype(np.int64), (k < lo) | (k > hi)


def active(t: npt.NDArray[np.float64], start: float = START, end: float | None = END) -> npt.NDArray[np.bool_]:
    on = t + 1e-9 >= start
    return on if end is None else on & (t + 1e-9 < end)


def delayed(x: npt.NDArray[np.float64], on: npt.NDArray[np.bool_], n: int) -> npt.NDArray[np.float64]:
    """``x`` where ``on``, each value replaced by the one ``n`` active samples before (the first until then)."""
    out = x.copy()
    idx = np.flatnonzero(on)
    out[idx] = x[idx[np.maximum(np.arange(idx.size) - n, 0)]]
    return out


def expected_inputs(kind: str, t: npt.NDArray[np.float64], true_v: npt.NDArray[np.float64], ch: int) -> npt.NDArray[np.float64]:
    """The faulted A/D voltages for the parameters of :data:`AD_CASES`."""
    v = true_v.copy()
    on = active(t)
    if kind == "open":
        v[on, ch] = 0.0
    elif kind == "open_value":
        v[on, ch] = -12.0
    elif kind == "short_ground":
        v[on, ch] = 0.0
    elif kind == "short_supply":
        v[on, ch] = 15.0
    elif kind == "stuck":
        v[on, ch] = true_v[np.flatnonzero(on)[0], ch]
    elif kind == "stuck_value":
        v[on, ch] = 2.5
    elif kind == "offset":
        v[on, ch] += 0.75
    elif kind == "gain":
        v[on, ch] *= 1.5
    elif kind == "noise":
        v[on, ch] += 0.2 * np.random.Generator(np.random.PCG64(7)).standard_normal(int(on.sum()))
    elif kind == "drift":
        v[on, ch] += 2.0 * (t[on] - START)
    elif kind == "intermittent":
        off = on & (np.fmod(t - START, 0.1) >= 0.3 * 0.1)
        v[off, ch] = 0.0
    elif kind == "delay":
        v[:, ch] = delayed(true_v[:, ch], on, 7)
    elif kind == "short_channels":
        mean = (true_v[on, 2] + true_v[on, 3]) / 2.0
        v[on, 2] = mean
        v[on, 3] = mean
    elif kind == "lost_bits":
        pass
    return v


AD_CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "open": ("AI3", {"kind": "open"}),
    "open_value": ("AI3", {"kind": "open", "value_v": -12.0}),
    "short_ground": ("AI3", {"kind": "short_ground"}),
    "short_supply": ("AI1", {"kind": "short_supply"}),
    "stuck": ("AI1", {"kind": "stuck"}),
    "stuck_value": ("AI4", {"kind": "stuck", "value_v": 2.5}),
    "offset": ("AI3", {"kind": "offset", "offset_v": 0.75}),
    "gain": ("AI2", {"kind": "gain", "factor": 1.5}),
    "noise": ("AI4", {"kind": "noise", "sigma_v": 0.2, "seed": 7}),
    "drift": ("AI1", {"kind": "drift", "rate_v_s": 2.0}),
    "intermittent": ("AI3", {"kind": "intermittent", "period_s": 0.1, "duty": 0.3}),
    "lost_bits": ("AI2", {"kind": "lost_bits", "bits": 3}),
    "delay": ("AI3", {"kind": "delay", "samples": 7}),
    "short_channels": ("AI3", {"kind": "short_channels", "other": "AI4"}),
}


@pytest.mark.parametrize("case", sorted(AD_CASES))
def test_tpdo1_codes_are_the_fault_of_the_truth(tmp_path: Path, case: str) -> None:
    channel, fault = AD_CASES[case]
    ch = int(channel[2]) - 1
    run = Run(tmp_path, [{"channel": channel, "start_s": START, "end_s": END, **fault}])
    assert len(run.codes) == len(run.t) > 200  # one TPDO1 per conversion
    want, saturated = quantize(expected_inputs(case, run.t, run.true_v, ch))
    if case == "lost_bits":
        on = active(run.t)
        want[on, ch] = (want[on, ch] >> 3) << 3
    np.testing.assert_array_equal(run.codes, want)
    np.testing.assert_array_equal(run.truth["channel_ad_saturated"], saturated)
    on = active(run.t)
    assert (run.codes[on, ch] != quantize(run.true_v)[0][on, ch]).any()  # the fault shows on the bus
    np.testing.assert_array_equal(run.codes[~on], quantize(run.true_v)[0][~on])  # and nowhere else
    if case == "short_supply":
        assert saturated[on, ch].all() and (run.codes[on, ch] == 2 ** (BITS - 1) - 1).all()


def expected_outputs(kind: str, commanded: npt.NDArray[np.float64], on: npt.NDArray[np.bool_], ch: int) -> npt.NDArray[np.float64]:
    v = commanded.copy()
    if kind == "open":
        v[on, ch] = 0.0
    elif kind == "stuck":
        v[on, ch] = commanded[np.flatnonzero(on)[0], ch]
    elif kind == "offset":
        v[on, ch] += -0.4
    elif kind == "gain":
        v[on, ch] *= 0.5
    elif kind == "saturate":
        v[on, ch] = np.clip(v[on, ch], -0.3, 0.3)
    elif kind == "delay":
        v[:, ch] = delayed(commanded[:, ch], on, 4)
    return v


DA_CASES: dict[str, tuple[str, dict[str, Any]]] = {
    "open": ("AO1", {"kind": "open"}),
    "stuck": ("AO2", {"kind": "stuck"}),
    "offset": ("AO1", {"kind": "offset", "offset_v": -0.4}),
    "gain": ("AO2", {"kind": "gain", "factor": 0.5}),
    "saturate": ("AO1", {"kind": "saturate", "limit_v": 0.3}),
    "delay": ("AO2", {"kind": "delay", "samples": 4}),
}


@pytest.mark.parametrize("case", sorted(DA_CASES))
def test_valves_get_the_fault_of_the_rpdo1_volts(tmp_path: Path, case: str) -> None:
    channel, fault = DA_CASES[case]
    ch = int(channel[2]) - 1
    run = Run(tmp_path, [{"channel": channel, "start_s": START, "end_s": END, **fault}], controller=MOVING)
    bus = (run.rpdo >> 4) * LSB  # the 12-bit D/A's volts from the bus's words
    commanded = run.truth["channel_da_commanded_v"]
    n = len(bus)
    assert n > 200
    np.testing.assert_array_equal(commanded[:n], bus)  # one D/A update per RPDO1...
    assert len(commanded) - n <= 2 and (commanded[n:] == 0.0).all()  # ...and the node's zero on leaving OPERATIONAL
    on = active(run.truth["channel_da_time_s"])
    applied = run.truth["channel_da_applied_v"]
    np.testing.assert_array_equal(applied, expected_outputs(case, commanded, on, ch))
    assert np.abs(commanded[on, ch]).max() > 0.4 and (applied[on, ch] != commanded[on, ch]).any()


def test_a_faulted_run_is_bit_identical_run_to_run(tmp_path: Path) -> None:
    faults = [
        {"channel": "AI4", "kind": "noise", "sigma_v": 0.3, "seed": 11, "start_s": 0.2},
        {"channel": "AI3", "kind": "drift", "rate_v_s": 1.0, "start_s": 0.4, "end_s": 1.0},
        {"channel": "AI3", "kind": "stuck", "start_s": 0.6, "end_s": 0.8},
        {"channel": "AO1", "kind": "gain", "factor": 0.7, "start_s": 0.3},
    ]
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    a, b = Run(tmp_path / "a", faults), Run(tmp_path / "b", faults)
    np.testing.assert_array_equal(a.tpdo, b.tpdo)
    np.testing.assert_array_equal(a.rpdo, b.rpdo)
    for key in a.truth:
        np.testing.assert_array_equal(a.truth[key], b.truth[key], err_msg=key)
    events = _recorded_events(tmp_path / "a" / "run.mcap")
    assert events == _recorded_events(tmp_path / "b" / "run.mcap")
    assert [(e["kind"], round(e["sim_time_s"], 6), e["detail"].split(" from ")[0]) for e in events] == [
        ("channel_fault", 0.2, "AI4 noise sigma_v=0.3 seed=11"),
        ("channel_fault", 0.3, "AO1 gain factor=0.7"),
        ("channel_fault", 0.4, "AI3 drift rate_v_s=1.0"),
        ("channel_fault", 0.6, "AI3 stuck"),
        ("channel_fault_cleared", 0.8, "AI3 stuck"),
        ("channel_fault_cleared", 1.0, "AI3 drift rate_v_s=1.0"),
    ]


def _recorded_events(path: Path) -> list[dict[str, Any]]:
    """The channel-fault events in a run's MCAP recording, in order, without their wall time."""
    with open(path, "rb") as f:
        events = [json.loads(m.data) for _, channel, m in make_reader(f).iter_messages() if channel.topic.endswith("/plant/events")]
    return [{k: v for k, v in e.items() if k != "wall_time_s"} for e in events if e["kind"].startswith("channel_fault")]


def test_seeded_noise_is_reproducible_and_the_seed_matters() -> None:
    def codes(seed: int) -> list[list[int]]:
        unit = ChannelFaultUnit(parse_channel_faults(json.dumps({"channel_faults": [{"channel": "AI2", "kind": "noise", "sigma_v": 0.5, "seed": seed}]})))
        return [unit.convert(k * 0.005, [1.0, 2.0, 3.0, 4.0], ConverterScale(BITS))[0] for k in range(50)]

    assert codes(3) == codes(3)
    assert codes(3) != codes(4)
    deviates = np.random.Generator(np.random.PCG64(3)).standard_normal(50)
    np.testing.assert_array_equal(np.array(codes(3))[:, 1], quantize(2.0 + 0.5 * deviates)[0])


def test_stacked_faults_act_in_the_documented_order() -> None:
    """gain, then offset, then stuck: the stuck value is the gained and offset one."""
    text = json.dumps(
        {
            "channel_faults": [
                {"channel": "AI1", "kind": "stuck", "start_s": 0.01},
                {"channel": "AI1", "kind": "offset", "offset_v": 1.0},
                {"channel": "AI1", "kind": "gain", "factor": 2.0},
            ]
        }
    )
    unit = ChannelFaultUnit(parse_channel_faults(text))
    scale = ConverterScale(BITS)
    first = unit.convert(0.0, [1.0, 0.0, 0.0, 0.0], scale)[0][0]
    held = unit.convert(0.01, [2.0, 0.0, 0.0, 0.0], scale)[0][0]
    later = unit.convert(0.02, [3.0, 0.0, 0.0, 0.0], scale)[0][0]
    assert first == quantize(np.array([1.0 * 2.0 + 1.0]))[0][0]
    assert held == later == quantize(np.array([2.0 * 2.0 + 1.0]))[0][0]


def test_insertion_and_removal_are_plant_events() -> None:
    settings = load_settings(
        PlantSettings,
        {
            "scenario": json.dumps({"channel_faults": [{"channel": "AI3", "kind": "short_ground", "start_s": 0.02, "end_s": 0.04}]}),
            "sensor_noise_scale": 0,
            "clock": "lockstep",
        },
    )
    events: list[Any] = []
    app = PlantApplication(settings, publish_event=events.append)
    codes = [app.on_sync(0)[0][2] for _ in range(10)]
    assert [(e.kind, round(e.sim_time_s, 6)) for e in events] == [("channel_fault", 0.02), ("channel_fault_cleared", 0.04)]
    assert "AI3 short_ground" in events[0].detail
    assert codes[3] == codes[4] == codes[5] == 0 and codes[2] != 0 and codes[7] != 0  # shorted from 0.02 s (the 4th sample) to 0.04 s


def test_without_channel_faults_the_node_path_is_untouched() -> None:
    settings = load_settings(PlantSettings, {"scenario": json.dumps([{"kind": "seed", "at_sim_time_s": 0.0, "seed": 3}])})
    assert PlantApplication(settings).channel_faults is None
    assert not parse_channel_faults("")
    assert parse_channel_faults("[]") == FaultSchedule()


BAD = {
    "unknown channel": ({"channel": "AI5", "kind": "open"}, "channel_faults item 0: channel: Input should be 'AI1', 'AI2', 'AI3', 'AI4', 'AO1' or 'AO2'"),
    "unknown kind": ({"channel": "AI1", "kind": "melt"}, "kind: Input should be 'open'"),
    "input kind on a valve": (
        {"channel": "AO1", "kind": "noise", "sigma_v": 1, "seed": 1},
        "'noise' is not a fault of a D/A output (AO1); allowed: open, stuck, offset, gain, saturate, delay",
    ),
    "valve kind on an input": (
        {"channel": "AI2", "kind": "saturate", "limit_v": 1},
        "'saturate' is not a fault of an A/D input (AI2); allowed: open, short_ground",
    ),
    "end before start": ({"channel": "AI1", "kind": "open", "start_s": 2.0, "end_s": 1.0}, "end_s 1.0 is not after start_s 2.0"),
    "missing parameter": ({"channel": "AI1", "kind": "offset"}, "a fault of kind 'offset' needs offset_v"),
    "parameter of another kind": ({"channel": "AI1", "kind": "open", "sigma_v": 1.0}, "a fault of kind 'open' takes value_v, not sigma_v"),
    "out of range": ({"channel": "AI1", "kind": "stuck", "value_v": 40.0}, "value_v: Input should be less than or equal to 15"),
    "valve stuck beyond full scale": ({"channel": "AO2", "kind": "stuck", "value_v": 12.0}, "a D/A output is stuck within +-10 V, not 12.0"),
    "short with itself": ({"channel": "AI3", "kind": "short_channels", "other": "AI3"}, "short_channels needs another channel than AI3"),
    "short with a valve": ({"channel": "AI3", "kind": "short_channels", "other": "AO1"}, "other: Input should be 'AI1', 'AI2', 'AI3' or 'AI4'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_fault_is_one_line_naming_it(case: str) -> None:
    item, message = BAD[case]
    with pytest.raises(ConfigError) as caught:
        parse_channel_faults(json.dumps({"channel_faults": [item]}))
    text = str(caught.value)
    assert "\n" not in text and message in text, text


def test_bad_section_and_bits_are_refused_at_settings_load() -> None:
    with pytest.raises(ConfigError, match=r"^.*has no section 'faults'; allowed: commands, channel_faults, stimulus$"):
        parse_channel_faults(json.dumps({"faults": []}))
    with pytest.raises(ConfigError) as caught:
        load_settings(PlantSettings, {"scenario": json.dumps({"channel_faults": [{"channel": "AI1", "kind": "lost_bits", "bits": 12}]})})
    assert "channel_faults item 0: lost_bits 12 leaves no bit of the 12-bit A/D (allowed 1..11)" in str(caught.value).splitlines()[-1]
    with pytest.raises(ConfigError) as caught:
        load_settings(PlantSettings, {"scenario": json.dumps({"channel_faults": [{"channel": "AI9", "kind": "open"}]})})
    assert "channel_faults item 0: channel: Input should be 'AI1'" in str(caught.value).splitlines()[-1]


def test_the_scenario_may_be_given_as_a_mapping() -> None:
    """As a YAML scenario file's ``settings: {plant: {scenario: {...}}}`` gives it."""
    faults = [{"channel": "AI3", "kind": "short_ground", "start_s": 5.0, "end_s": 7.0}]
    settings = load_settings(PlantSettings, {"scenario": {"commands": [{"kind": "seed", "at_sim_time_s": 1.0, "seed": 2}], "channel_faults": faults}})
    assert parse_channel_faults(settings.scenario).faults[0].describe() == "AI3 short_ground from 5 s until 7 s"


class _Opaque:
    """A plant model whose A/D voltages cannot be read before its converter."""

    def __init__(self, arm: Any) -> None:
        self._arm = arm

    def __getattr__(self, name: str) -> Any:
        if name in ("sample_volts", "adc_scale"):
            raise AttributeError(name)
        return getattr(self._arm, name)


def test_input_faults_on_a_model_without_input_voltages_are_refused_at_start() -> None:
    settings = load_settings(PlantSettings, {"scenario": {"channel_faults": [{"channel": "AI1", "kind": "open"}]}})
    model = _Opaque(PlantApplication(load_settings(PlantSettings, {})).arm)
    with pytest.raises(ConfigError) as caught:
        PlantApplication(settings, arm=model)
    assert str(caught.value) == "channel_faults on the A/D inputs need a model whose input voltages can be read; _Opaque has no sample_volts"
    valves_only = load_settings(PlantSettings, {"scenario": {"channel_faults": [{"channel": "AO1", "kind": "open"}]}})
    assert PlantApplication(valves_only, arm=model).channel_faults is not None  # the D/A side needs nothing of the model
