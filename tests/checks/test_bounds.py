"""stays_within and rms_below on signals whose answer is known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workbench.checks import Signal, rms_below, stays_within

T = np.arange(0.0, 4.0, 0.001)
SINE = Signal.of(T, 0.3 * np.sin(2 * np.pi * 2.0 * T), "defl", "in")  # four whole periods: RMS 0.3/√2


def test_a_sine_stays_within_a_band_wider_than_its_amplitude() -> None:
    result = stays_within(SINE, -0.31, 0.31)
    assert result.passed
    assert abs(result.measured) == pytest.approx(0.3, abs=1e-6) and result.limit in (-0.31, 0.31)
    assert "stayed within [-0.31, 0.31] in" in result.explain()


def test_a_sine_leaves_a_narrower_band_and_the_samples_outside_are_counted() -> None:
    result = stays_within(SINE, -0.2, 0.2)
    assert result.level == "FAIL"
    expected = np.count_nonzero(np.abs(SINE.values) > 0.2)
    assert result.details["samples_outside"] == expected
    assert f"{expected} of {len(SINE)} samples outside" in result.explain()


def test_from_a_time_on_only_the_later_samples_count() -> None:
    sig = Signal.of(T, np.where(T < 1.0, 5.0, 0.0), "x")
    assert stays_within(sig, -1, 1).level == "FAIL"
    assert stays_within(sig, -1, 1, from_s=1.0).passed


def test_a_non_finite_sample_is_outside() -> None:
    values = SINE.values.copy()
    values[100] = math.nan
    assert stays_within(SINE.derive(values, "defl"), -1.0, 1.0).level == "FAIL"


def test_a_band_upside_down_is_refused() -> None:
    with pytest.raises(ValueError, match="above"):
        stays_within(SINE, 1.0, -1.0)


def test_rms_of_a_sine_is_its_amplitude_over_root_two() -> None:
    result = rms_below(SINE, 0.22)
    assert result.measured == pytest.approx(0.3 / math.sqrt(2.0), rel=1e-6)
    assert result.passed
    assert rms_below(SINE, 0.2).level == "FAIL"


def test_rms_about_the_mean_is_the_standard_deviation() -> None:
    shifted = SINE.derive(SINE.values + 1.0, "defl")
    assert rms_below(shifted, 10.0).measured == pytest.approx(math.sqrt(1.0 + 0.045), rel=1e-6)
    assert rms_below(shifted, 10.0, remove_mean=True).measured == pytest.approx(np.std(shifted.values), rel=1e-12)


def test_empty_windows_and_unmeasurable_signals_compare_nothing() -> None:
    assert stays_within(SINE, -1, 1, from_s=10.0).level == "INVALID"
    assert stays_within(Signal.of([], [], "x"), -1, 1).level == "INVALID"
    assert rms_below(Signal.of([0.0], [0.0], "x"), 1.0).level == "INVALID"
    values = SINE.values.copy()
    values[3] = math.inf
    result = rms_below(SINE.derive(values, "defl"), 1.0)
    assert result.level == "INVALID" and "1 non-finite" in result.explain()
