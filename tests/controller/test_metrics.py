"""The §4.2.1 cost functions against analytic signals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.metrics import (
    CostReport,
    acceleration_filter,
    deflection_acceleration,
    deflection_velocity,
    percent_of_baseline,
    rms_costs,
    velocity_filter,
)

TS = 0.005


def sinusoid(f: float, amp: float, seconds: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(int(seconds / TS)) * TS
    return t, amp * np.sin(2 * math.pi * f * t + 0.3)


@pytest.mark.parametrize("f", [0.3, 0.5])
def test_derivatives_of_a_slow_sinusoid_within_one_percent(f: float) -> None:
    amp = 0.4
    w = 2 * math.pi * f
    _, x = sinusoid(f, amp)
    v = deflection_velocity(x, TS)
    a = deflection_acceleration(x, TS)
    true_v = amp * w * np.cos(w * v.t_s + 0.3)
    true_a = -amp * w * w * np.sin(w * a.t_s + 0.3)
    assert np.max(np.abs(v.values - true_v)) < 0.01 * amp * w
    assert np.max(np.abs(a.values - true_a)) < 0.01 * amp * w * w


@pytest.mark.parametrize("f", [2.0, 3.6, 5.0, 8.0])
def test_derivatives_of_a_mode_scaled_by_the_filter_gain(f: float) -> None:
    """At the modes' frequencies the regressions are low-pass: the estimate is the true
    derivative times the filter's gain (and in phase, for the centred alignment)."""
    amp = 0.01
    w = 2 * math.pi * f
    _, x = sinusoid(f, amp)
    vf, af = velocity_filter(TS), acceleration_filter(TS)
    v, a = vf.apply(x), af.apply(x)
    true_v = amp * w * np.cos(w * v.t_s + 0.3) * vf.gain(f)
    true_a = -amp * w * w * np.sin(w * a.t_s + 0.3) * af.gain(f)
    np.testing.assert_allclose(v.values, true_v, atol=1e-9 * amp * w)
    np.testing.assert_allclose(a.values, true_a, atol=1e-9 * amp * w * w)
    assert vf.gain(5.0) == pytest.approx(0.941, abs=1e-3)
    assert af.gain(5.0) == pytest.approx(0.463, abs=1e-3)


@settings(max_examples=50, deadline=None)
@given(
    c=st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3),
    t0=st.floats(-5.0, 5.0),
)
def test_exact_on_polynomials(c: list[float], t0: float) -> None:
    t = t0 + np.arange(100) * TS
    x = c[0] + c[1] * t + c[2] * t**2
    # rounding: a few ulps of the signal times the taps' absolute sum
    tol_a = 1e-13 * np.max(np.abs(x)) * np.abs(acceleration_filter(TS).taps).sum() + 1e-9
    np.testing.assert_allclose(deflection_acceleration(x, TS).values, 2 * c[2], rtol=0, atol=tol_a)
    lin = c[0] + c[1] * t
    tol_v = 1e-13 * np.max(np.abs(lin)) * np.abs(velocity_filter(TS).taps).sum() + 1e-9
    np.testing.assert_allclose(deflection_velocity(lin, TS).values, c[1], rtol=0, atol=tol_v)


def test_windows_times_and_alignment() -> None:
    x = np.arange(100.0) ** 2 * TS**2  # x = t^2: v = 2 t, a = 2
    v = deflection_velocity(x, TS)
    assert v.values.shape == (91,)
    assert v.t_s[0] == pytest.approx(4.5 * TS)
    np.testing.assert_allclose(v.values, 2 * v.t_s, atol=1e-9)  # exact at the window centre
    causal = deflection_velocity(x, TS, alignment="causal")
    np.testing.assert_allclose(causal.values, v.values)  # same taps: slope is constant on the window
    np.testing.assert_allclose(causal.t_s, v.t_s + 4.5 * TS)
    a = deflection_acceleration(x, TS)
    assert a.values.shape == (61,) and a.t_s[0] == pytest.approx(19.5 * TS)
    np.testing.assert_allclose(a.values, 2.0, atol=1e-6)
    assert velocity_filter(TS).taps.size == 10 and acceleration_filter(TS).taps.size == 40
    with pytest.raises(ValueError):
        deflection_acceleration(np.zeros(39), TS)
    with pytest.raises(ValueError):
        velocity_filter(TS, alignment="sideways")  # type: ignore[arg-type]


def test_rms_costs_per_link_and_percent_of_baseline() -> None:
    f1, f2, amp1, amp2 = 3.6, 5.0, 0.02, 0.005
    _, x1 = sinusoid(f1, amp1, 20.0)
    _, x2 = sinusoid(f2, amp2, 20.0)
    cost = rms_costs(np.column_stack([x1, x2]), TS)
    vf, af = velocity_filter(TS), acceleration_filter(TS)
    for i, (f, amp) in enumerate([(f1, amp1), (f2, amp2)]):
        w = 2 * math.pi * f
        assert cost.velocity_rms[i] == pytest.approx(amp * w * vf.gain(f) / math.sqrt(2), rel=0.01)
        assert cost.acceleration_rms[i] == pytest.approx(amp * w * w * af.gain(f) / math.sqrt(2), rel=0.01)
    single = rms_costs(x1, TS)
    assert single.velocity_rms.shape == (1,)
    assert single.velocity_rms[0] == pytest.approx(cost.velocity_rms[0])
    pct = percent_of_baseline(CostReport(cost.velocity_rms / 2, cost.acceleration_rms), cost)
    np.testing.assert_allclose(pct.velocity_rms, 50.0)
    np.testing.assert_allclose(pct.acceleration_rms, 100.0)
    assert set(cost.as_dict()) == {"velocity_rms", "acceleration_rms"}
