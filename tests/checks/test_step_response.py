"""settles_within and overshoot_below against references nobody here wrote: the
analytic second-order step response, scipy.signal's simulation of the
transfer function and python-control's step_info."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal as sps

from workbench.checks import Signal, overshoot_below, settles_within

WN = 2.0 * math.pi * 1.5  # rad/s
DT = 1e-3


def second_order_step(zeta: float, wn: float = WN, duration_s: float = 8.0, gain: float = 1.0) -> Signal:
    """The step response of gain·wn²/(s² + 2ζ wn s + wn²), simulated by scipy.signal."""
    t = np.arange(0.0, duration_s, DT)
    _, y = sps.step(sps.TransferFunction([gain * wn * wn], [1.0, 2.0 * zeta * wn, wn * wn]), T=t)
    return Signal.of(t, y, "y", "rad")


def analytic_overshoot_pct(zeta: float) -> float:
    return 100.0 * math.exp(-zeta * math.pi / math.sqrt(1.0 - zeta * zeta))


def settling_bound_s(zeta: float, band: float, wn: float = WN) -> float:
    """The time the response's envelope e^(-ζ wn t)/√(1-ζ²) enters the band: the
    response is inside from then on, so its settling time is at most this."""
    return math.log(1.0 / (band * math.sqrt(1.0 - zeta * zeta))) / (zeta * wn)


@pytest.mark.parametrize("zeta", [0.1, 0.3, 0.5, 0.7])
def test_overshoot_matches_the_analytic_second_order_value(zeta: float) -> None:
    result = overshoot_below(second_order_step(zeta), limit_pct=100.0, final=1.0)
    assert result.passed
    assert result.measured == pytest.approx(analytic_overshoot_pct(zeta), rel=1e-3)


@pytest.mark.parametrize("zeta", [0.2, 0.5, 0.7])
def test_settling_time_is_within_the_envelope_bound(zeta: float) -> None:
    bound = settling_bound_s(zeta, 0.02)
    result = settles_within(second_order_step(zeta), within_s=bound, band_pct=2.0, final=1.0)
    assert result.passed, result.line()
    assert 0.5 * bound < result.measured <= bound  # the envelope's bound is not loose by more than 2x here


@pytest.mark.parametrize("zeta", [0.15, 0.4, 0.6])
@pytest.mark.parametrize("gain", [1.0, 2.5])
def test_overshoot_and_settling_agree_with_python_control(zeta: float, gain: float) -> None:
    control = pytest.importorskip("control")
    sig = second_order_step(zeta, gain=gain)
    info = control.step_info(sig.values, sig.t, SettlingTimeThreshold=0.02)
    over = overshoot_below(sig, limit_pct=100.0)
    settle = settles_within(sig, within_s=100.0, band_pct=2.0)
    assert over.measured == pytest.approx(info["Overshoot"], rel=1e-9, abs=1e-9)
    assert abs(settle.measured - info["SettlingTime"]) <= DT  # one sample: the band's edge taken as in or out


def test_a_step_downwards_is_measured_in_its_own_direction() -> None:
    up = second_order_step(0.3)
    down = Signal.of(up.t, 5.0 - up.values, "y_down")
    assert overshoot_below(down, 100.0, final=4.0).measured == pytest.approx(analytic_overshoot_pct(0.3), rel=1e-3)
    assert settles_within(down, 10.0, final=4.0).measured == pytest.approx(settles_within(up, 10.0, final=1.0).measured)


def test_overshoot_above_the_limit_fails_with_its_line() -> None:
    result = overshoot_below(second_order_step(0.2), limit_pct=10.0)
    assert not result.passed and result.level == "FAIL"
    assert result.explain().startswith(f"overshoot {analytic_overshoot_pct(0.2):.1f} % against a limit of 10 %")


def test_a_slow_response_fails_settling_and_one_still_moving_never_settled() -> None:
    slow = second_order_step(0.1)
    result = settles_within(slow, within_s=1.0, final=1.0)
    assert result.level == "FAIL" and result.measured > 1.0
    cut = Signal.of(slow.t[:600], slow.values[:600], "y")  # ends while still ringing
    never = settles_within(cut, within_s=1.0, final=1.0)
    assert never.level == "FAIL" and math.isinf(never.measured) and "never settled" in never.explain()


def test_start_time_counts_from_the_step() -> None:
    base = second_order_step(0.5)
    delayed = Signal.of(np.concatenate([np.arange(-2.0, 0.0, DT), base.t]) + 2.0, np.concatenate([np.zeros(2000), base.values]), "y")
    assert settles_within(delayed, 5.0, start_s=2.0, final=1.0).measured == pytest.approx(settles_within(base, 5.0, final=1.0).measured)


@pytest.mark.parametrize("values", [[], [1.0], [0.0, 1.0]])
def test_too_short_a_signal_compares_nothing(values: list[float]) -> None:
    sig = Signal.of(np.arange(len(values), dtype=float), values, "y")
    for result in (settles_within(sig, 1.0), overshoot_below(sig, 10.0)):
        assert result.level == "INVALID" and not result.passed
        assert result.explain().startswith("compared nothing")


def test_no_step_and_a_window_past_the_end_compare_nothing() -> None:
    flat = Signal.of(np.arange(10.0), np.ones(10), "y")
    assert overshoot_below(flat, 10.0).level == "INVALID"
    assert settles_within(flat, 1.0).level == "INVALID"
    assert settles_within(second_order_step(0.5), 1.0, start_s=100.0).level == "INVALID"
    assert settles_within(flat, 1.0, band=0.1).passed  # a band given: a flat signal is settled
