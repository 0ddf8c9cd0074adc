"""Each stimulus shape against a reference nobody here wrote: scipy.signal's
chirp and maximal-length sequence, numpy's interp and scipy's previous-value
interpolation, numpy's sine."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.interpolate import interp1d
from scipy.signal import chirp, max_len_seq

from protocol.stimulus import parse_stimulus
from protocol.stimulus_eval import StimulusSource, prbs_bits, profile_value, table

TS = 0.005


def _one(item: dict[str, object], side: str = "controller"):  # type: ignore[no-untyped-def]
    (profile,) = parse_stimulus([item], side).profiles  # type: ignore[arg-type]
    return profile


def _series(item: dict[str, object], t: np.ndarray, side: str = "controller") -> np.ndarray:
    p = _one(item, side)
    data = table(p)
    return np.array([profile_value(p, data, float(x)) for x in t])


def test_a_step_holds_its_size_inside_its_window_and_is_zero_outside() -> None:
    t = np.arange(0, 3, TS)
    v = _series({"input": "valve.u1", "shape": "step", "size": 1.7, "at_s": 1.0, "for_s": 0.5}, t)
    inside = (t >= 1.0 - 1e-9) & (t < 1.5 - 1e-9)
    assert np.all(v[inside] == 1.7) and np.all(v[~inside] == 0.0)
    assert inside.sum() == 100


def test_a_ramp_to_a_value_is_numpy_interp_of_its_corners() -> None:
    t = np.arange(0, 4, TS)
    v = _series({"input": "setpoint.phi1", "shape": "ramp", "to": 0.1, "over_s": 1.5, "at_s": 0.5, "end_s": 3.0}, t)
    ref = np.interp(t, [0.5, 2.0], [0.0, 0.1]) * ((t >= 0.5 - 1e-9) & (t < 3.0 - 1e-9))
    np.testing.assert_allclose(v, ref, rtol=0, atol=1e-15)
    by_slope = _series({"input": "setpoint.phi1", "shape": "ramp", "slope": -0.05, "at_s": 1.0, "for_s": 2.0}, t)
    ref = np.interp(t, [1.0, 3.0], [0.0, -0.1]) * ((t >= 1.0 - 1e-9) & (t < 3.0 - 1e-9))
    np.testing.assert_allclose(by_slope, ref, rtol=0, atol=1e-15)


def test_a_sine_is_numpys_sine_of_the_time_since_its_start() -> None:
    t = np.arange(0, 3, TS)
    v = _series({"input": "valve.u2", "shape": "sine", "amplitude": 0.8, "f_hz": 3.3, "phase_rad": 0.4, "offset": 0.2, "at_s": 0.7}, t)
    on = t >= 0.7 - 1e-9
    tau = np.where(on, t - 0.7, 0.0)
    np.testing.assert_allclose(v, np.where(on, 0.2 + 0.8 * np.sin(2 * np.pi * 3.3 * tau + 0.4), 0.0), rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["linear", "logarithmic"])
def test_a_chirp_is_scipys_chirp_over_its_duration(method: str) -> None:
    t = np.arange(0, 12, TS)
    item = {
        "input": "valve.u1",
        "shape": "chirp",
        "amplitude": 1.5,
        "f0_hz": 0.5,
        "f1_hz": 12.0,
        "duration_s": 8.0,
        "method": method,
        "phase_deg": -90.0,
        "at_s": 2.0,
    }
    v = _series(item, t)
    on = (t >= 2.0 - 1e-9) & (t < 10.0 - 1e-9)
    ref = np.where(on, 1.5 * chirp(np.where(on, t - 2.0, 0.0), f0=0.5, t1=8.0, f1=12.0, method=method, phi=-90.0), 0.0)
    np.testing.assert_allclose(v, ref, rtol=0, atol=1e-9)
    assert np.count_nonzero(v[~on]) == 0


def test_prbs_holds_each_bit_of_a_maximal_length_sequence() -> None:
    n = 7
    item = {"input": "valve.u1", "shape": "prbs", "amplitude": 0.5, "bit_s": 0.02, "seed": 5, "register_bits": n}
    period = 2**n - 1
    t = np.arange(0, 2 * period * 0.02, TS)
    v = _series(item, t)
    per_bit = v.reshape(-1, 4)  # 4 ticks per bit
    assert np.all(per_bit == per_bit[:, :1])
    bits = per_bit[:, 0] / 0.5
    assert set(np.unique(bits)) == {-1.0, 1.0}
    assert np.array_equal(bits[:period], bits[period:])  # period 2**n - 1
    # the two-valued circular autocorrelation of an m-sequence: N at lag 0, -1 at every other lag
    x = bits[:period]
    acf = np.real(np.fft.ifft(np.abs(np.fft.fft(x)) ** 2))
    np.testing.assert_allclose(acf, np.r_[period, -np.ones(period - 1)], atol=1e-9)
    # another seed starts the same sequence elsewhere: a cyclic shift of scipy's
    ref = max_len_seq(n)[0] * 2.0 - 1.0
    for seed in (0, 5, 77):
        seq = prbs_bits(n, seed)
        assert any(np.array_equal(seq, np.roll(ref, -k)) for k in range(period))
    assert not np.array_equal(prbs_bits(n, 5), prbs_bits(n, 6))


def test_playback_linear_is_numpy_interp_and_zoh_is_the_previous_sample(tmp_path: Path) -> None:
    src_t = np.array([0.0, 0.3, 0.35, 1.2, 2.0])
    src_v = np.array([0.0, 1.0, -2.0, 0.5, 0.25])
    csv = tmp_path / "profile.csv"
    csv.write_text("t,value\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(src_t, src_v, strict=True)))
    t = np.arange(0, 3.0, TS)
    at = 0.5
    lin = _series({"input": "valve.u2", "shape": "playback", "csv": str(csv), "at_s": at}, t)
    on = (t >= at - 1e-9) & (t < at + 2.0 - 1e-9)
    tau = t - at
    np.testing.assert_allclose(lin[on], np.interp(tau[on], src_t, src_v), rtol=0, atol=1e-12)
    assert np.all(lin[~on] == 0.0)
    zoh = _series({"input": "valve.u2", "shape": "playback", "csv": str(csv), "at_s": at, "hold": "zoh"}, t)
    previous = interp1d(src_t, src_v, kind="previous", bounds_error=False, fill_value=(src_v[0], src_v[-1]))
    np.testing.assert_allclose(zoh[on], previous(np.round(tau[on], 9)), rtol=0, atol=0)


def test_playback_from_a_controller_record_column_and_inline(tmp_path: Path) -> None:
    rec = tmp_path / "run.npz"
    t_s = np.arange(0, 1, TS)
    np.savez(rec, t_s=t_s, u1_v=np.sin(7 * t_s))
    t = np.arange(0, 1.5, TS)
    v = _series({"input": "valve.u1", "shape": "playback", "npz": str(rec), "column": "u1_v", "scale": 2.0}, t)
    on = t < t_s[-1] - 1e-9
    np.testing.assert_allclose(v[on], 2.0 * np.sin(7 * t[on]), atol=1e-12)
    inline = _series({"input": "valve.u1", "shape": "playback", "t": [0.0, 1.0], "values": [0.0, 3.0], "for_s": 1.5}, t)
    np.testing.assert_allclose(inline, np.interp(t, [0.0, 1.0], [0.0, 3.0]), atol=1e-12)


def test_playback_from_a_recordings_topic_field(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / "run.mcap"
    times = np.arange(0, 2, 0.05)
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        schema = w.register_schema(name="GroundTruth", encoding="jsonschema", data=b"{}")
        channel = w.register_channel(topic="/ralf/r1/plant/truth", message_encoding="json", schema_id=schema)
        other = w.register_channel(topic="/ralf/r1/plant/events", message_encoding="json", schema_id=schema)
        for k, tt in enumerate(times):
            data = {"sim_time_s": float(tt), "deflections_in": [0.0, float(np.cos(tt))]}
            w.add_message(channel, log_time=k, publish_time=k, data=json.dumps(data).encode())
            w.add_message(other, log_time=k, publish_time=k, data=b'{"sim_time_s": 0.0}')
        w.finish()
    t = np.arange(0, 1.9, TS)
    v = _series(
        {"input": "disturbance.link2", "shape": "playback", "mcap": str(path), "topic": "plant/truth", "field": "deflections_in.1", "scale": 10}, t, "plant"
    )
    np.testing.assert_allclose(v, 10 * np.interp(t, times, np.cos(times)), atol=1e-12)


def test_profiles_on_one_input_add_in_order_and_their_sum_is_clipped_to_its_range() -> None:
    plan = parse_stimulus(
        [
            {"input": "valve.u1", "shape": "step", "size": 6.0, "at_s": 1.0},
            {"input": "valve.u1", "shape": "sine", "amplitude": 2.0, "f_hz": 1.0, "at_s": 0.0},
            {"input": "valve.u1", "shape": "step", "size": 7.0, "at_s": 2.0, "for_s": 1.0},
            {"input": "valve.u2", "shape": "step", "size": -1.0, "at_s": 0.5},
        ],
        "controller",
    )
    src = StimulusSource(plan)
    for t in np.arange(0, 4, 0.01):
        expected = (6.0 if t >= 1.0 - 1e-9 else 0.0) + 2.0 * np.sin(2 * np.pi * t) + (7.0 if 2.0 - 1e-9 <= t < 3.0 - 1e-9 else 0.0)
        assert src.value("valve.u1", float(t)) == pytest.approx(min(10.0, max(-10.0, expected)), abs=1e-12)
    assert src.value("valve.u1", 2.25) == 10.0  # 6 + 2 + 7 clipped
    assert src.value("setpoint.phi1", 2.0) == 0.0 and not src.any_active("setpoint.phi1", 2.0)
    assert src.any_active("valve.u2", 0.5) and not src.any_active("valve.u2", 0.49)
    changes = src.transitions(0.0) + src.transitions(1.0) + src.transitions(2.5) + src.transitions(3.0)
    assert [(c.index, c.started, c.time_s) for c in changes] == [(1, True, 0.0), (0, True, 1.0), (3, True, 0.5), (2, True, 2.0), (2, False, 3.0)]


def test_evaluation_is_deterministic_and_pure() -> None:
    item = {"input": "valve.u1", "shape": "prbs", "amplitude": 1.0, "bit_s": 0.01, "seed": 3}
    t = np.arange(0, 5, TS)
    a = _series(item, t)
    b = _series(item, t[::-1])[::-1]  # asked backwards: the same values
    assert np.array_equal(a, b)
