"""The OATF input-shaping filter (thesis §3.3 [3-32 ... 3-35]) against independent references."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, reject, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy import signal

from controller.oatf import (
    OatfConfig,
    OatfDesignError,
    OatfFilter,
    OatfSupervisor,
    StageDesign,
    cascade_kernel,
    design_stage,
    design_stage_continuous,
    frequency_response,
    integer_delay_samples,
    kernel_impulses,
    residual_vibration,
    robust_delay_s,
    three_term_coefficients,
    transfer_function,
)

TS = 0.005


def pole_z(f_hz: float, zeta: float, ts: float) -> complex:
    """The design mode's pole s = -zeta w_n + j w_d mapped to z = e^(s Ts)."""
    wn = 2 * math.pi * f_hz
    return complex(np.exp((-zeta * wn + 1j * wn * math.sqrt(1 - zeta**2)) * ts))


def zvd(f_hz: float, zeta: float) -> np.ndarray:
    """Singer and Seering's ZVD shaper amplitudes [1, 2K, K^2] / (1 + K)^2, K = e^(-zeta pi / sqrt(1 - zeta^2))."""
    k = math.exp(-zeta * math.pi / math.sqrt(1 - zeta**2))
    return np.array([1.0, 2 * k, k * k]) / (1 + k) ** 2


# --------------------------------------------------------------------------- design


@settings(max_examples=200, deadline=None)
@given(
    f=st.floats(0.5, 95.0),
    zeta=st.floats(0.0, 0.3),
    n1=st.integers(1, 80),
)
def test_unit_dc_gain_and_zero_at_design_mode_for_any_integer_delay(f: float, zeta: float, n1: int) -> None:
    try:
        stage = design_stage(f, zeta, TS, delay_samples=n1)
    except OatfDesignError:
        reject()  # w_d n1 Ts a multiple of 2 pi with no damping: 0/0
    scale = stage.abs_coefficient_sum
    # Summing coefficients of size ~scale rounds at ~scale * eps (near-degenerate
    # designs reach 1e5: f=66.671875, zeta=1e-05, n1=24 sums to 1 - 7e-12).
    assert sum(stage.coefficients) == pytest.approx(1.0, abs=1e-12 * max(1.0, scale))
    assert abs(transfer_function(1.0, [stage])) == pytest.approx(1.0, abs=1e-9)
    assert abs(transfer_function(pole_z(f, zeta, TS), [stage])) < 1e-9 * scale
    amps, times = kernel_impulses([stage])
    assert residual_vibration(amps, times, f, zeta) < 1e-9 * scale


def test_thesis_example_51_hz_at_500_hz() -> None:
    """The discrete design (coefficients from n1 Ts) has a zero at 51 Hz; the design from the
    continuous delay T1 = pi / w_d, taps at n1 = int(T1 / Ts) = 4, does not."""
    ts = 0.002
    discrete = design_stage(51.0, 0.0, ts)
    continuous = design_stage_continuous(51.0, 0.0, ts)
    assert discrete.delay_samples == continuous.delay_samples == 4 == int(robust_delay_s(51.0, 0.0) / ts)
    mag_discrete = abs(frequency_response([51.0], [discrete])[0])
    mag_continuous = abs(frequency_response([51.0], [continuous])[0])
    assert mag_discrete < 1e-12
    assert mag_continuous > 0.08  # cos^2(pi 51 / 125): its zero sits at 62.5 Hz instead
    assert mag_continuous == pytest.approx(math.cos(math.pi * 51 / 125) ** 2, rel=1e-9)
    # with damping: the discrete design still cancels the mode, the continuous one leaves ~7 %
    for zeta in (0.02, 0.09):
        d = kernel_impulses([design_stage(51.0, zeta, ts)])
        c = kernel_impulses([design_stage_continuous(51.0, zeta, ts)])
        assert residual_vibration(*d, 51.0, zeta) < 1e-12
        assert residual_vibration(*c, 51.0, zeta) > 0.05


@settings(max_examples=100, deadline=None)
@given(f=st.floats(0.5, 50.0), zeta=st.floats(0.0, 0.5))
def test_robust_delay_gives_the_zvd_shaper(f: float, zeta: float) -> None:
    coeffs = three_term_coefficients(f, zeta, robust_delay_s(f, zeta))
    np.testing.assert_allclose(coeffs, zvd(f, zeta), rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(design_stage_continuous(f, zeta, TS).coefficients, zvd(f, zeta), rtol=1e-9)


@pytest.mark.parametrize("n1", [5, 10, 25, 40])
def test_discrete_design_is_zvd_when_the_robust_delay_is_whole_samples(n1: int) -> None:
    zeta = 0.09
    f_n = 1.0 / (2 * n1 * TS) / math.sqrt(1 - zeta**2)  # pi / w_d = n1 Ts exactly
    stage = design_stage(f_n, zeta, TS)
    assert stage.delay_samples == n1
    np.testing.assert_allclose(stage.coefficients, zvd(f_n, zeta), rtol=1e-9)


def test_integer_delay_truncates_and_is_at_least_one() -> None:
    assert integer_delay_samples(0.05, 0.005) == 10
    assert integer_delay_samples(0.0499, 0.005) == 9
    assert integer_delay_samples(0.001, 0.005) == 1
    with pytest.raises(OatfDesignError):
        integer_delay_samples(0.0, 0.005)


def test_design_rejects_bad_modes() -> None:
    for f, z in [(0.0, 0.1), (-1.0, 0.1), (math.nan, 0.1), (5.0, 1.0), (5.0, -0.1)]:
        with pytest.raises(OatfDesignError):
            design_stage(f, z, TS)
    with pytest.raises(OatfDesignError):
        design_stage(100.0, 0.05, TS)  # not below Nyquist
    with pytest.raises(OatfDesignError):
        three_term_coefficients(5.0, 0.0, 0.2)  # w_d T = 2 pi, undamped: 0/0


def test_cascade_of_two_modes_has_zeros_at_both() -> None:
    stages = [design_stage(4.0, 0.0, TS), design_stage(11.0, 0.0, TS)]
    mags = np.abs(frequency_response([4.0, 11.0, 0.0], stages))
    assert mags[0] < 1e-12 and mags[1] < 1e-12
    assert mags[2] == pytest.approx(1.0)
    damped = [design_stage(4.0, 0.09, TS), design_stage(11.0, 0.05, TS)]
    assert abs(transfer_function(pole_z(4.0, 0.09, TS), damped)) < 1e-12
    assert abs(transfer_function(pole_z(11.0, 0.05, TS), damped)) < 1e-12
    delays, weights = cascade_kernel(damped)
    assert weights.sum() == pytest.approx(1.0)
    assert delays.max() == 2 * (damped[0].delay_samples + damped[1].delay_samples)
    # the dense kernel's DFT is the frequency response
    dense = np.zeros(delays.max() + 1)
    dense[delays] = weights
    f = np.linspace(0, 100, 37)
    ref = np.array([np.sum(dense * np.exp(-2j * np.pi * fi * TS * np.arange(dense.size))) for fi in f])
    np.testing.assert_allclose(frequency_response(f, damped), ref, atol=1e-12)


# --------------------------------------------------------------------------- residual vibration


def test_residual_vibration_reference_values() -> None:
    assert residual_vibration([1.0], [0.0], 5.0, 0.09) == pytest.approx(1.0)
    # undamped ZVD: V(r) = cos^2(pi r / 2) with r = w / w_design
    t = np.array([0.0, 0.1, 0.2])  # pi / w for 5 Hz
    r = np.linspace(0.5, 1.5, 11)
    np.testing.assert_allclose(residual_vibration(zvd(5.0, 0.0), t, 5.0 * r, 0.0), np.cos(np.pi * r / 2) ** 2, atol=1e-12)
    with pytest.raises(ValueError):
        residual_vibration([1.0, 2.0], [0.0], 5.0, 0.1)


def mode_step_residual(u: np.ndarray, f_hz: float, zeta: float, ts: float, t_end_index: int) -> float:
    """Simulate y'' + 2 zeta w y' + w^2 y = w^2 u (zero-order hold, exact discretisation) and
    return the amplitude of the free vibration about the final value after sample ``t_end_index``."""
    w = 2 * math.pi * f_hz
    a = np.array([[0.0, 1.0], [-(w**2), -2 * zeta * w]])
    b = np.array([[0.0], [w**2]])
    ad, bd, *_ = signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), ts, method="zoh")
    x = np.zeros(2)
    for k in range(t_end_index):
        x = ad @ x + bd[:, 0] * u[k]
    dev, vel = x[0] - u[-1], x[1]
    sigma, wd = zeta * w, w * math.sqrt(1 - zeta**2)
    return math.hypot(dev, (vel + sigma * dev) / wd)


@pytest.mark.parametrize(
    "design_hz, delay",
    [(5.0, None), (5.0, 0.05), (6.0, None), (4.0, 0.05), (10.0, None)],
)
def test_shaped_step_on_a_5_hz_mode(design_hz: float, delay: float | None) -> None:
    """A shaped unit step on a 5 Hz, zeta = 0.09 mode (the §4.3 simulation's mode): tuned right the
    residual vibration vanishes; mistuned it matches the residual-vibration formula."""
    f, zeta = 5.0, 0.09
    cfg = OatfConfig(delay_mode="robust" if delay is None else "fixed", fixed_delay_s=delay or 0.05)
    filt = OatfFilter([design_hz], n_channels=1, config=cfg)
    n_end = filt.total_delay_samples
    u = filt.process(np.ones(n_end + 1))
    shaped = mode_step_residual(u, f, zeta, TS, n_end)
    unshaped = mode_step_residual(np.ones(1), f, zeta, TS, 0)
    assert unshaped == pytest.approx(1 / math.sqrt(1 - zeta**2))
    predicted = float(residual_vibration(*kernel_impulses(filt.stages), f, zeta))
    assert shaped / unshaped == pytest.approx(predicted, abs=1e-9)
    if design_hz == f:
        assert shaped / unshaped < 1e-6
    else:
        assert shaped / unshaped < 0.7  # still far below the unshaped step


# --------------------------------------------------------------------------- filter object


def test_filter_step_and_process_agree_and_filter_many_channels() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(700, 3))
    a = OatfFilter([3.7, 9.0], n_channels=3)
    b = OatfFilter([3.7, 9.0], n_channels=3)
    stepped = np.array([a.step(xi) for xi in x])
    blocks = np.concatenate([b.process(x[:13]), b.process(x[13:500]), b.process(x[500:])])
    np.testing.assert_allclose(stepped, blocks, atol=1e-12)
    delays, weights = a.kernel
    dense = np.zeros(delays.max() + 1)
    dense[delays] = weights
    ref = np.stack([np.convolve(x[:, c], dense)[: len(x)] for c in range(3)], axis=1)
    np.testing.assert_allclose(stepped, ref, atol=1e-12)
    np.testing.assert_allclose(a.history(5), x[-5:])


def test_reset_to_a_value_is_a_steady_state() -> None:
    """Outer location: start the filter at the initial set-point, not at zero."""
    filt = OatfFilter([4.0], n_channels=2, initial=[1.2, 0.7])
    out = np.array([filt.step([1.2, 0.7]) for _ in range(50)])
    np.testing.assert_allclose(out, np.tile([1.2, 0.7], (50, 1)), atol=1e-12)


def test_update_modes_keeps_the_delay_line_and_the_delays() -> None:
    filt = OatfFilter([4.0], n_channels=1)
    n1 = filt.stages[0].delay_samples
    t = np.arange(400) * TS
    x = np.sin(2 * np.pi * 0.7 * t) + 0.3 * t
    before = filt.process(x[:300])
    hist = filt.history()
    old_delays, old_weights = filt.kernel
    filt.update_modes([5.5])
    np.testing.assert_array_equal(filt.history(), hist)  # state untouched
    assert filt.stages[0].delay_samples == n1  # delay fixed during the run
    assert filt.stages[0].frequency_hz == 5.5
    after = filt.process(x[300:])
    # reference: the old kernel up to the switch, the new one after, both on the full input history
    new_delays, new_weights = filt.kernel
    ref_new = sum(w * np.concatenate([np.zeros(d), x])[: len(x)] for d, w in zip(new_delays, new_weights))
    ref_old = sum(w * np.concatenate([np.zeros(d), x])[: len(x)] for d, w in zip(old_delays, old_weights))
    np.testing.assert_allclose(before, ref_old[:300], atol=1e-12)
    np.testing.assert_allclose(after, ref_new[300:], atol=1e-12)
    # a constant input passes an update without a jump (both designs have unit DC gain)
    const = OatfFilter([4.0], n_channels=1, initial=2.0)
    y0 = const.step(2.0)
    const.update_modes([5.0])
    assert const.step(2.0) == pytest.approx(y0, abs=1e-12)


def test_adapt_delay_recomputes_the_delay() -> None:
    filt = OatfFilter([4.0], n_channels=1, config=OatfConfig(adapt_delay=True))
    filt.update_modes([8.0])
    assert filt.stages[0].delay_samples == integer_delay_samples(robust_delay_s(8.0, 0.09), TS)
    fixed = OatfFilter([4.0], n_channels=1, config=OatfConfig(delay_mode="fixed", fixed_delay_s=0.05))
    assert fixed.stages[0].delay_samples == 10
    fixed.update_modes([4.0, 9.0])  # a new mode gets the configured delay
    assert [s.delay_samples for s in fixed.stages] == [10, 10]
    fixed.update_modes([])
    np.testing.assert_allclose(fixed.step([3.0]), [3.0])  # no modes: identity


def test_guards_reject_large_alternating_coefficients_and_long_delays() -> None:
    cfg = OatfConfig(delay_mode="fixed", fixed_delay_s=0.05)
    OatfFilter([3.0], config=cfg)  # sum|a| 3.9: accepted
    with pytest.raises(OatfDesignError, match="sum"):
        OatfFilter([2.0], config=cfg)  # sum|a| 9.5
    robust = OatfFilter([4.0], n_channels=1)  # n1 = 25 samples, 0.125 s
    before = robust.stages
    with pytest.raises(OatfDesignError):
        robust.update_modes([8.0])  # 0.125 s is a whole period of 8 Hz: 1 / (1 - K)^2 gains
    assert robust.stages == before  # unchanged on rejection
    with pytest.raises(OatfDesignError, match="total"):
        OatfFilter([1.0, 1.0, 1.0], config=OatfConfig(max_total_delay_s=2.0))  # 3 x 1 s
    with pytest.raises(ValidationError):
        OatfConfig(plausible_band_hz=(5.0, 1.0))


def test_supervisor_ignores_and_counts_implausible_estimates() -> None:
    filt = OatfFilter([10.0, 20.0], n_channels=2, config=OatfConfig(min_confidence=0.5, plausible_band_hz=(1.0, 30.0)))
    sup = OatfSupervisor(filt)
    assert sup.offer([4.2, 25.0], confidence=[0.9, 0.1]) is True
    assert [s.frequency_hz for s in filt.stages] == [4.2, 20.0]
    assert sup.counts.low_confidence == 1 and sup.counts.estimates_used == 1
    assert sup.offer([0.3, math.nan]) is False  # out of band, non-finite
    assert sup.counts.out_of_band == 1 and sup.counts.non_finite == 1
    assert sup.offer([4.2, 20.0, 7.0]) is False  # nothing changed; one extra estimate
    assert sup.counts.extra_estimates == 1
    assert sup.offer([100.0, 17.0], confidence=0.9) is True
    assert sup.counts.out_of_band == 2
    assert [s.frequency_hz for s in filt.stages] == [4.2, 17.0]
    # a merged design that fails the guards is rejected and counted; the filter keeps its design
    fixed = OatfFilter([5.0], n_channels=1, config=OatfConfig(delay_mode="fixed"))
    sup2 = OatfSupervisor(fixed)
    assert sup2.offer([1.5]) is False
    assert sup2.counts.design_rejected == 1 and "sum" in sup2.counts.last_rejection
    assert fixed.stages[0].frequency_hz == 5.0
    assert sup2.offer([6.0]) is True and sup2.counts.updates == 1


def test_one_stage_kernel_is_the_convolution() -> None:
    for f in (1.5, 4.4, 9.9, 19.0):
        stage = design_stage(f, 0.09, 0.005)
        delays, weights = cascade_kernel([stage])
        n = stage.delay_samples
        poly = np.zeros(2 * n + 1)
        poly[[0, n, 2 * n]] = stage.coefficients
        dense = np.convolve(np.ones(1), poly)
        assert delays.tolist() == np.flatnonzero(dense).tolist() and weights.tolist() == dense[np.flatnonzero(dense)].tolist()
    zero_middle = StageDesign(4.0, 0.0, 3, 0.005, (0.5, 0.0, 0.5))
    delays, weights = cascade_kernel([zero_middle])
    assert delays.tolist() == [0, 6] and weights.tolist() == [0.5, 0.5]
