"""mode_frequency_within, detected_within and no_deadline_miss_streak."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from workbench.checks import Signal, detected_within, mode_frequency_within, no_deadline_miss_streak
from workbench.checks.deadlines import longest_streak

T = np.arange(0.0, 10.0, 0.15)
TRUTH = Signal.of(np.arange(0.0, 10.0, 0.05), 4.5 - 0.01 * np.arange(0.0, 10.0, 0.05), "truth_f1", "Hz")


def identified(offset_pct: float, nan_before: float = 0.0) -> Signal:
    f = (4.5 - 0.01 * T) * (1.0 + offset_pct / 100.0)
    return Signal.of(T, np.where(T < nan_before, math.nan, f), "f_id", "Hz")


def test_identified_within_a_relative_tolerance_of_a_truth_series() -> None:
    result = mode_frequency_within(identified(3.0), TRUTH, rel_tol=0.05)
    assert result.passed and result.measured == pytest.approx(3.0, rel=1e-6) and result.unit == "%"
    assert mode_frequency_within(identified(6.0), TRUTH, rel_tol=0.05).level == "FAIL"


def test_identified_within_an_absolute_tolerance_of_a_value() -> None:
    sig = Signal.of(T, np.full(T.size, 4.6), "f_id", "Hz")
    result = mode_frequency_within(sig, 4.5, abs_tol=0.15)
    assert result.passed and result.measured == pytest.approx(0.1) and result.unit == "Hz"
    assert mode_frequency_within(sig, 4.5, abs_tol=0.05).level == "FAIL"


def test_samples_that_identified_nothing_are_missing() -> None:
    late = identified(1.0, nan_before=3.0)
    assert mode_frequency_within(late, TRUTH, rel_tol=0.05).level == "FAIL"  # none allowed by default
    assert mode_frequency_within(late, TRUTH, rel_tol=0.05, from_s=3.0).passed
    assert mode_frequency_within(late, TRUTH, rel_tol=0.05, max_missing=0.35).passed
    result = mode_frequency_within(identified(1.0, nan_before=100.0), TRUTH, rel_tol=0.05)
    assert result.level == "INVALID" and "identified nothing" in result.explain()


def test_a_tolerance_is_given_exactly_once() -> None:
    with pytest.raises(ValueError, match="exactly one"):
        mode_frequency_within(identified(0.0), TRUTH)
    with pytest.raises(ValueError, match="exactly one"):
        mode_frequency_within(identified(0.0), TRUTH, rel_tol=0.1, abs_tol=0.1)


def test_an_empty_identification_or_truth_compares_nothing() -> None:
    assert mode_frequency_within(Signal.of([], [], "f"), TRUTH, rel_tol=0.1).level == "INVALID"
    assert mode_frequency_within(identified(0.0), Signal.of([], [], "truth"), rel_tol=0.1).level == "INVALID"


EVENTS_T = np.array([2.0, 7.0])


def test_a_detection_within_the_latency_limit() -> None:
    cause = Signal(np.array([5.0]), np.array([1.0]), "events.payload", kind="events")
    ident = Signal.of(T, np.where(T >= 6.2, 5.3, 4.5), "f_id", "Hz")
    detection = ident.where(lambda f: f > 5.0, "f_id > 5 Hz")
    result = detected_within(cause, detection, within_s=1.5)
    assert result.passed and result.measured == pytest.approx(T[T >= 6.2][0] - 5.0)
    late = detected_within(cause, detection, within_s=1.0)
    assert late.level == "FAIL" and "against a limit of 1 s" in late.explain()


def test_a_detection_before_the_cause_does_not_count() -> None:
    detection = Signal(EVENTS_T, np.ones(2), "events.watchdog", kind="events")
    assert detected_within(1.0, detection, 1.5).measured == pytest.approx(1.0)
    assert detected_within(3.0, detection, 5.0).measured == pytest.approx(4.0)
    never = detected_within(7.5, detection, 1.0)
    assert never.level == "FAIL" and math.isinf(never.measured) and "no events.watchdog after" in never.explain()


def test_a_cause_that_never_came_or_a_series_too_short_compares_nothing() -> None:
    no_cause = Signal(np.array([]), np.array([]), "events.payload", kind="events")
    assert detected_within(no_cause, Signal.of(T, np.ones(T.size), "x"), 1.0).level == "INVALID"
    short = Signal.of(T[:10], np.zeros(10), "x")  # ends at 1.35 s
    result = detected_within(1.0, short, 2.0)
    assert result.level == "INVALID" and "before the limit" in result.explain()
    assert detected_within(0.0, Signal.of([], [], "x"), 1.0).level == "INVALID"


@given(st.lists(st.booleans(), max_size=60))
def test_longest_streak_matches_itertools_groupby(flags: list[bool]) -> None:
    expected = max((len(list(g)) for k, g in itertools.groupby(flags) if k), default=0)
    assert longest_streak(np.array(flags, dtype=float))[0] == expected


def test_a_miss_series_streak_against_the_limit() -> None:
    flags = np.array([0, 1, 0, 1, 1, 1, 0, 0, 1, 1, 0], dtype=float)
    misses = Signal.of(np.arange(flags.size) * 0.15, flags, "interrupts.deadline_missed")
    result = no_deadline_miss_streak(misses, 3)
    assert result.passed and result.measured == 3 and result.details["misses"] == 6
    failed = no_deadline_miss_streak(misses, 2)
    assert failed.level == "FAIL" and "3 deadline misses in a row from 0.45 s" in failed.explain()
    assert no_deadline_miss_streak(misses.derive(np.zeros(flags.size), "m"), 0).passed


def test_a_run_max_counter_is_the_streak_and_a_count_only_bounds_it() -> None:
    at_end = np.array([10.0])
    assert no_deadline_miss_streak(Signal(at_end, np.array([2.0]), "health.controller.deadline_miss_run_max", kind="run_max"), 1).level == "FAIL"
    assert no_deadline_miss_streak(Signal(at_end, np.array([1.0]), "health.controller.deadline_miss_run_max", kind="run_max"), 1).passed
    assert no_deadline_miss_streak(Signal(at_end, np.array([0.0]), "counters.deadline_misses", kind="count"), 1).passed
    unknown = no_deadline_miss_streak(Signal(at_end, np.array([5.0]), "counters.deadline_misses", kind="count"), 1)
    assert unknown.level == "INVALID" and "per-tick" in unknown.explain()


def test_no_miss_samples_compare_nothing() -> None:
    assert no_deadline_miss_streak(Signal.of([], [], "m"), 1).level == "INVALID"
    assert no_deadline_miss_streak(Signal.of([0.0, 1.0], [0.0, math.nan], "m"), 1).level == "INVALID"
