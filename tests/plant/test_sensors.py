"""Sensors and A/D: quantization, noise levels of §3.1.1, saturation, anti-alias filter."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from plant_emulator.model import PlantConfig, RalfArm
from plant_emulator.model import period_kernel as pk
from plant_emulator.sensors import AntiAliasFilter, analog_noise_std, channel_lsb_in
from protocol.can_map import ConverterScale

SPEC_STD_IN = np.array([5.4e-3, 4.6e-3, 2.1e-3, 3.8e-4])


def _rest_readings(bits: int, n: int = 4000, seed: int = 4) -> np.ndarray:
    arm = RalfArm(PlantConfig(seed=seed, adc_bits=bits))
    out = np.empty((n, 4))
    for k in range(n):
        arm.advance(0.005)
        out[k] = arm.sample().values_in
    return out


def test_quantization_error_is_at_most_half_an_lsb() -> None:
    rng = np.random.default_rng(0)
    for bits in (12, 16, 20):
        arm = RalfArm(PlantConfig(sensor_noise=False))
        arm.set_adc_bits(bits)
        lsb = ConverterScale(bits).lsb_v
        for _ in range(200):
            arm.set_valve_voltages(0.05 * rng.standard_normal(2))
            arm.advance(0.005)
            r = arm.sample()
            t = arm.truth()
            assert not r.saturated.any()
            assert np.all(np.abs(r.volts - r.analog_volts) <= lsb / 2 + 1e-12)
            truth = np.array([*t.extensions_in, *t.sensed_deflections_in])
            lsb_in = np.array([channel_lsb_in(c, bits) for c in range(4)])
            assert np.all(np.abs(r.values_in - truth) <= lsb_in / 2 + 1e-12)
            assert np.array_equal(r.codes, np.rint(r.analog_volts / lsb).astype(np.int64))


def test_noise_std_at_rest_matches_the_thesis_at_12_bits() -> None:
    x = _rest_readings(12)
    std = x.std(axis=0)
    assert std == pytest.approx(SPEC_STD_IN, rel=0.08)


def test_finer_converters_remove_only_the_quantization_part() -> None:
    analog = np.array([analog_noise_std(s, channel_lsb_in(c, 12)) for c, s in enumerate(SPEC_STD_IN)])
    for bits in (16, 20):
        std = _rest_readings(bits, n=3000, seed=8).std(axis=0)
        assert std == pytest.approx(analog, rel=0.08)
    # the link-2 deflection (noise ~ 1.4 LSB at 12 bits) gains the most
    assert analog[3] / SPEC_STD_IN[3] < 0.98


def test_saturation_is_flagged_not_wrapped() -> None:
    # aim the deflection sensors 1 in off: both channels read beyond full scale
    arm = RalfArm(PlantConfig(deflection_zero_in=(-1.0, 1.0)))
    r = arm.sample()
    sc = ConverterScale(12)
    assert list(r.saturated) == [False, False, True, True]
    assert r.codes[2] == sc.code_max and r.codes[3] == sc.code_min
    arm.set_adc_bits(16)
    r = arm.sample()
    assert r.codes[2] == ConverterScale(16).code_max and r.saturated[2]


def test_antialias_filter_is_a_butterworth_below_nyquist() -> None:
    f = AntiAliasFilter(40.0, 0.001)
    z = np.exp(2j * np.pi * np.array([1e-3, 5.0, 40.0, 100.0]) * 0.001)
    mag = np.array([abs(np.linalg.solve(zi * np.eye(2) - f.Ad, f.Bd)[0]) for zi in z])
    assert mag[0] == pytest.approx(1.0, abs=1e-6)  # DC gain 1
    assert mag[1] > 0.99  # flat over the modes
    assert mag[2] == pytest.approx(2**-0.5, rel=0.03)  # -3 dB at the cutoff
    assert 20 * np.log10(mag[3]) < -14.0  # the 100 Hz Nyquist of 200 Hz sampling


def test_the_kernels_antialias_step_is_scipys_zoh_butterworth() -> None:
    """The period kernel's filter step against scipy: butter (analog), cont2discrete (ZOH), dlsim."""
    h, fc = 0.001, 40.0
    b, a = scipy.signal.butter(2, 2 * np.pi * fc, analog=True)
    ad, bd, cd, dd, _ = scipy.signal.cont2discrete(scipy.signal.tf2ss(b, a), h, method="zoh")
    u = np.random.default_rng(3).normal(size=(400, 2)).cumsum(axis=0) * 0.01  # a wandering input per channel
    st = np.zeros(pk.STATE_SIZE)
    sp = np.zeros(pk.SP_SIZE)
    sp[pk.SP_FILTER : pk.SP_FILTER + 6] = AntiAliasFilter(fc, h)._c
    got = np.empty_like(u)
    for k in range(u.shape[0]):
        for j in (0, 1):
            pk.antialias_step(st, sp, j, float(u[k, j]))
            got[k, j] = st[pk.ST_ANTIALIAS + 2 * j]
    for j in (0, 1):
        _, want, _ = scipy.signal.dlsim((ad, bd, cd, dd, h), u[:, j])
        np.testing.assert_allclose(got[:-1, j], want[1:, 0], rtol=1e-11, atol=1e-15)  # the output after step k is scipy's at k + 1


def test_deflection_noise_is_band_limited_by_the_filter() -> None:
    x = _rest_readings(20, n=4000, seed=9)[:, 2]
    fr, p = scipy.signal.welch(x, fs=200.0, nperseg=256)
    low = p[(fr > 1) & (fr < 20)].mean()
    high = p[(fr > 80) & (fr < 100)].mean()
    assert high < 0.2 * low
