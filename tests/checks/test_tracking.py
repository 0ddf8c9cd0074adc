"""follows_reference against known delays: a chirp (scipy.signal.chirp) and its
delayed copy, and the response of a known transfer function (scipy.signal.lsim)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal as sps

from workbench.checks import Signal, follows_reference
from workbench.checks.tracking import estimate_lag

DT = 0.005
T = np.arange(0.0, 10.0, DT)
CHIRP = sps.chirp(T, f0=0.2, t1=10.0, f1=3.0)


def delayed(samples: int, values: np.ndarray = CHIRP) -> np.ndarray:
    return np.concatenate([np.full(samples, values[0]), values[: values.size - samples]])


@pytest.mark.parametrize("samples", [0, 1, 7, 37])
def test_a_delayed_copy_gives_its_delay_and_no_error(samples: int) -> None:
    result = follows_reference(Signal.of(T, CHIRP, "ref", "rad"), Signal.of(T, delayed(samples), "out", "rad"), tolerance=1e-9, max_lag_s=0.2)
    assert result.passed, result.line()
    assert result.details["lag_s"] == pytest.approx(samples * DT, abs=1e-12)
    assert result.measured <= 1e-12


def test_a_lead_is_a_negative_lag() -> None:
    lead = np.concatenate([CHIRP[12:], np.full(12, CHIRP[-1])])
    result = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(T, lead, "out"), tolerance=1e-9, max_lag_s=0.1)
    assert result.details["lag_s"] == pytest.approx(-12 * DT)


def test_a_delay_beyond_the_limit_fails_and_says_so() -> None:
    result = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(T, delayed(30), "out"), tolerance=0.01, max_lag_s=0.1)
    assert result.level == "FAIL" and result.measured <= 1e-12  # the error after the lag is nil: the lag alone fails it
    assert "out follows ref 150 ms behind (limit 100 ms)" in result.explain()
    beyond = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(T, delayed(60), "out"), tolerance=0.01, max_lag_s=0.1)
    assert beyond.level == "FAIL" and "at least 200 ms behind" in beyond.explain()  # past the search: said so


def test_the_lag_of_a_first_order_filter_is_its_group_delay() -> None:
    """A first-order lag 1/(τs+1) on a slow sine delays it by atan(ωτ)/ω (its phase over ω)."""
    tau, f = 0.05, 0.5
    w = 2 * np.pi * f
    t = np.arange(0.0, 20.0, DT)
    u = np.sin(w * t)
    _, y, _ = sps.lsim(sps.TransferFunction([1.0], [tau, 1.0]), u, t)
    delay = np.arctan(w * tau) / w
    gain = 1.0 / np.sqrt(1.0 + (w * tau) ** 2)
    result = follows_reference(Signal.of(t, u, "u"), Signal.of(t, y, "y"), tolerance=1.05 * (1.0 - gain) + 0.002, max_lag_s=0.1, start_s=2.0)
    assert abs(result.details["lag_s"] - delay) <= DT
    assert result.passed, result.line()
    too_tight = follows_reference(Signal.of(t, u, "u"), Signal.of(t, y, "y"), tolerance=0.5 * (1.0 - gain), max_lag_s=0.1, start_s=2.0)
    assert too_tight.level == "FAIL" and "against a tolerance" in too_tight.explain()


def test_an_error_beyond_the_tolerance_fails() -> None:
    bumped = delayed(5) + np.where((T > 4.0) & (T < 4.5), 0.2, 0.0)
    result = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(T, bumped, "out"), tolerance=0.1, max_lag_s=0.1)
    assert result.level == "FAIL" and result.measured == pytest.approx(0.2, abs=1e-9)


def test_signals_on_other_times_are_interpolated() -> None:
    coarse = T[::2]
    result = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(coarse, delayed(4)[::2], "out"), tolerance=0.02, max_lag_s=0.05)
    assert result.passed and result.details["lag_s"] == pytest.approx(4 * DT)


def test_estimate_lag_is_the_least_squares_shift() -> None:
    rng = np.random.default_rng(3)
    noisy = delayed(9) + 0.05 * rng.standard_normal(T.size)
    k, mse = estimate_lag(CHIRP, noisy, 20)
    brute = [np.mean((noisy[20 + j : T.size - 20 + j] - CHIRP[20 : T.size - 20]) ** 2) for j in range(-20, 21)]
    assert k == 9 == int(np.argmin(brute)) - 20
    np.testing.assert_allclose(mse, brute, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("n", [0, 3])
def test_empty_or_short_signals_compare_nothing(n: int) -> None:
    result = follows_reference(Signal.of(T[:n], CHIRP[:n], "ref"), Signal.of(T[:n], CHIRP[:n], "out"), tolerance=1.0, max_lag_s=1.0)
    assert result.level == "INVALID" and not result.passed


def test_signals_that_do_not_overlap_compare_nothing() -> None:
    result = follows_reference(Signal.of(T, CHIRP, "ref"), Signal.of(T + 20.0, CHIRP, "out"), tolerance=1.0, max_lag_s=1.0)
    assert result.level == "INVALID" and "overlap" in result.explain()


def test_a_constant_reference_has_no_lag_to_find() -> None:
    rng = np.random.default_rng(1)
    result = follows_reference(
        Signal.of(T, np.ones(T.size), "ref"), Signal.of(T, 1 + 0.001 * rng.standard_normal(T.size), "out"), tolerance=0.01, max_lag_s=0.05
    )
    assert result.passed and result.details["lag_s"] == 0.0 and "no lag to estimate" in result.explain()


def test_signals_in_different_units_are_refused() -> None:
    with pytest.raises(ValueError, match="ref is in rad, out in deg"):
        follows_reference(Signal.of(T, CHIRP, "ref", "rad"), Signal.of(T, CHIRP, "out", "deg"), tolerance=1.0, max_lag_s=1.0)
