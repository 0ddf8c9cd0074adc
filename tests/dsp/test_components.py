"""History, averaging/RLS, smoothing, and configuration (test 6 of the brief)."""

from __future__ import annotations

import numpy as np
import pydantic
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from dsp_service.history import HistoryBuffer
from dsp_service.identifier import Identifier, IdentifierConfig
from dsp_service.smoothing import FrequencySmoother
from dsp_service.spectra import SpectralAverager

from .synth import dataset

N = 512


# ----------------------------------------------------------------------- history
@settings(max_examples=60, deadline=None)
@given(st.integers(4, 64), st.lists(st.integers(0, 150), min_size=1, max_size=12))
def test_history_holds_the_last_n_samples(n: int, batches: list[int]) -> None:
    hist = HistoryBuffer(n)
    total = sum(batches)
    data = np.arange(4 * total, dtype=float).reshape(4, total) + 1.0
    pos = 0
    for b in batches:
        hist.append(data[:2, pos : pos + b], data[2:, pos : pos + b])
        pos += b
    expected = np.zeros((4, n))
    keep = min(n, total)
    if keep:
        expected[:, n - keep :] = data[:, total - keep :]
    np.testing.assert_array_equal(hist.view(), expected)
    assert hist.samples_seen == total
    assert hist.samples_in_history == keep
    assert hist.is_full == (total >= n)


def test_resize_zeroes_history() -> None:
    hist = HistoryBuffer(8)
    hist.append(np.ones((2, 5)), np.ones((2, 5)))
    hist.resize(16)
    assert hist.n == 16 and hist.samples_seen == 0
    assert np.all(hist.view() == 0)


def test_fft_width_change_zeroes_history_and_averages() -> None:
    _, u, y = dataset(8 * N, seed=2)
    idf = Identifier(IdentifierConfig(fft_width=N))
    for s in range(0, 8 * N, N // 2):
        idf.push(u[:, s : s + N // 2], y[:, s : s + N // 2])
        idf.step()
    assert idf.effective_averages > 1 and idf.samples_in_history == N
    idf.set_fft_width(2 * N)
    assert idf.cfg.fft_width == 2 * N
    assert idf.samples_in_history == 0 and idf.effective_averages == 0.0
    assert np.all(idf.history.view() == 0) and idf.history.n == 2 * N
    assert idf.transfer_functions().freqs_hz.size == N + 1
    result = idf.step()
    assert result.poles == () and result.confidence == 0.0
    with pytest.raises(pydantic.ValidationError):
        idf.set_fft_width(1001)  # odd


def test_batches_longer_than_history_and_empty_batches() -> None:
    idf = Identifier(IdentifierConfig(fft_width=N))
    idf.push(np.zeros((2, 0)), np.zeros((2, 0)))
    assert idf.samples_in_history == 0
    rng = np.random.default_rng(0)
    u, y = rng.standard_normal((2, 3 * N)), rng.standard_normal((2, 3 * N))
    idf.push(u, y)
    np.testing.assert_array_equal(idf.history.view()[:2], u[:, -N:])
    assert idf.history.samples_seen == 3 * N


# --------------------------------------------------------------------- averaging
def test_exponential_averager_is_the_recursion_2_9() -> None:
    """S ← (1 − α) S + α S_new, including across the internal rescaling."""
    rng = np.random.default_rng(1)
    alpha = 0.3
    avg = SpectralAverager((3,), 64, "exponential", alpha)
    ref = np.zeros(3, dtype=complex)
    for k in range(800):  # (1 − 0.3)^−800 ≫ 1e100: several rescalings
        new = rng.standard_normal(3) + 1j * rng.standard_normal(3)
        avg.update(new, 16)
        ref = new if k == 0 else (1 - alpha) * ref + alpha * new
    np.testing.assert_allclose(avg.mean(), ref, rtol=1e-10)
    assert avg.kish_averages == pytest.approx((2 - alpha) / alpha, rel=1e-9)
    # overlapping snapshots (16 new samples of a 64-sample window) hold fewer independent averages
    assert avg.effective_averages == pytest.approx(1 + 2 * 16 * (avg.kish_averages - 1) / 64)


def test_linear_averager_is_the_mean() -> None:
    rng = np.random.default_rng(2)
    xs = rng.standard_normal((50, 4)) + 1j * rng.standard_normal((50, 4))
    avg = SpectralAverager((4,), 8, "linear")
    for x in xs:
        avg.update(x, 8)
    np.testing.assert_allclose(avg.mean(), xs.mean(axis=0), rtol=1e-12)
    assert avg.kish_averages == pytest.approx(50)


@pytest.mark.parametrize("solver", ["mimo", "uncorrelated"])
def test_rls_equals_exponential_averaging_with_alpha_one_minus_lambda(solver: str) -> None:
    """Per-bin RLS [D.28, D.29] (vector form for MIMO) ≈ exponential averaging, α = 1 − λ."""
    _, u, y = dataset(40 * N, seed=5)
    lam = 0.9
    a = Identifier(IdentifierConfig(fft_width=N, averaging="rls", rls_forgetting=lam, solver=solver))
    b = Identifier(IdentifierConfig(fft_width=N, averaging="exponential", alpha=1 - lam, solver=solver))
    for s in range(0, u.shape[1], N // 2):
        for idf in (a, b):
            idf.push(u[:, s : s + N // 2], y[:, s : s + N // 2])
            ra = idf.step()
    rb = b.step()
    ra = a.step()
    ta, tb = a.transfer_functions(smoothed=False), b.transfer_functions(smoothed=False)
    np.testing.assert_array_equal(ta.valid, tb.valid)
    # compare where the inputs carry power (they are low-passed at 40 Hz): in
    # unexcited, ill-conditioned bins the RLS recursion's rounding (and its
    # vanishing λ^k regularisation) dominates, as RLS's known numerics predict
    sel = ta.valid & (ta.freqs_hz <= 50.0)
    assert sel.sum() > 0.95 * (ta.freqs_hz <= 50.0).sum()
    for name in ("h11", "h12", "h21", "h22", "htot"):
        ha, hb = getattr(ta, name)[sel], getattr(tb, name)[sel]
        np.testing.assert_allclose(ha, hb, rtol=1e-6, atol=1e-9 * np.abs(hb).max(), err_msg=name)
    assert len(ra.poles) == len(rb.poles) > 0
    for pa, pb in zip(ra.poles, rb.poles):
        assert pa.frequency_hz == pytest.approx(pb.frequency_hz, rel=1e-6)
        assert pa.damping_ratio == pytest.approx(pb.damping_ratio, rel=1e-5)


# --------------------------------------------------------------------- smoothing
def test_savgol_on_complex_keeps_the_imaginary_part() -> None:
    rng = np.random.default_rng(3)
    x = rng.standard_normal(300) + 1j * rng.standard_normal(300)
    sm = FrequencySmoother(300, 17, 2)
    got = sm.smooth(x)
    ref = scipy.signal.savgol_filter(x.real, 17, 2, mode="interp") + 1j * scipy.signal.savgol_filter(x.imag, 17, 2, mode="interp")
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=1e-12)
    imag_only = sm.smooth(1j * x.imag)
    assert np.all(imag_only.real == 0) and np.abs(imag_only.imag).max() > 0.1
    # a polynomial of the filter's order passes unchanged, edges included
    k = np.arange(300.0)
    poly = (0.5 + 2j) + (0.01 - 0.02j) * k + 1e-4j * k * k
    np.testing.assert_allclose(sm.smooth(poly), poly, rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.sampled_from([(0, 0), (5, 2), (9, 4), (17, 2), (17, 3), (25, 4)]), st.integers(0, 1000))
def test_smoothing_of_every_bin_is_scipys_and_valid_where_its_window_is(wo: tuple[int, int], seed: int) -> None:
    """The downloads' smoothing against scipy's savgol_filter (mode='interp') to 1e-12 (the filter
    sums each window in order, scipy convolves), and a smoothed bin valid iff its whole fitting window is."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(121) + 1j * rng.standard_normal(121)
    sm = FrequencySmoother(121, *wo)
    if wo[0] > 1:
        ref = scipy.signal.savgol_filter(x.real, wo[0], wo[1], mode="interp") + 1j * scipy.signal.savgol_filter(x.imag, wo[0], wo[1], mode="interp")
    else:
        ref = x
    np.testing.assert_allclose(sm.smooth(x), ref, rtol=1e-12, atol=1e-12 * np.abs(x).max())
    np.testing.assert_allclose(sm.smooth(np.stack([x, 2 * x]))[1], 2 * ref, rtol=1e-12, atol=1e-12 * np.abs(x).max())
    valid = rng.random(121) > 0.05
    full = sm.valid(valid)
    w = max(wo[0], 1)
    for kk in range(121):
        s0 = min(max(kk - w // 2, 0), 121 - w)
        assert full[kk] == valid[s0 : s0 + w].all()


# ------------------------------------------------------------------------ config
@pytest.mark.parametrize(
    "bad",
    [
        dict(fft_width=1001),
        dict(search_max_hz=150.0),
        dict(search_min_hz=10.0, search_max_hz=5.0),
        dict(smoothing_window=16),
        dict(smoothing_window=5, smoothing_order=5),
        dict(alpha=0.0),
        dict(averaging="median"),
        dict(unknown_field=1),
    ],
)
def test_config_validation(bad: dict) -> None:
    with pytest.raises(pydantic.ValidationError):
        IdentifierConfig(**bad)


def test_config_is_frozen_and_defaults() -> None:
    cfg = IdentifierConfig()
    assert (cfg.fft_width, cfg.alpha, cfg.smoothing_window, cfg.smoothing_order) == (2048, 0.1, 17, 2)
    with pytest.raises(pydantic.ValidationError):
        cfg.alpha = 0.2  # type: ignore[misc]  # writing the frozen field is the test


def test_smoothing_off_and_estimate_on_smoothed_paths_run() -> None:
    _, u, y = dataset(30 * N, seed=4)
    for kw in (
        dict(smoothing_window=0),
        dict(estimate_on_smoothed=True),
        dict(peak_source="21"),
        dict(damping_method="fwhm", fwhm_exact=False),
        dict(log_weighting=False),
    ):
        idf = Identifier(IdentifierConfig(fft_width=N, **kw))
        for s in range(0, u.shape[1], N // 2):
            idf.push(u[:, s : s + N // 2], y[:, s : s + N // 2])
            result = idf.step()
        assert result.poles, kw
        for p in result.poles:
            assert p.damping_ratio is not None and 0 < p.damping_ratio < 0.5
        if kw.get("damping_method") == "fwhm":
            assert result.poles[0].damping_ratio == result.poles[0].damping_fwhm


# ------------------------------------------------------------ service-facing API
def test_run_time_alpha_change_and_history_restart() -> None:
    _, u, y = dataset(20 * N, seed=6)
    idf = Identifier(IdentifierConfig(fft_width=N))
    for s in range(0, 10 * N, N // 2):
        idf.push(u[:, s : s + N // 2], y[:, s : s + N // 2])
        idf.step()
    before = idf.effective_averages
    idf.set_alpha(0.05)
    assert idf.cfg.alpha == 0.05 and idf.samples_in_history == N
    assert idf.effective_averages == before  # nothing lost
    idf.restart_history()
    assert idf.samples_in_history == 0 and idf.effective_averages == before
    idf.push(u[:, 10 * N : 10 * N + N // 2], y[:, 10 * N : 10 * N + N // 2])
    idf.step()  # history not full again yet: nothing averaged
    assert idf.effective_averages == before
    assert idf.fft_width == N
    tf = idf.transfer_functions()
    assert tf.H11 is tf.h11 and tf.Htot is tf.htot
    rls = Identifier(IdentifierConfig(fft_width=N, averaging="rls"))
    rls.set_alpha(0.2)
    assert rls.cfg.rls_forgetting == pytest.approx(0.8)
    with pytest.raises(pydantic.ValidationError):
        idf.set_alpha(0.0)


def test_the_removed_kernel_setting_is_refused_naming_the_compiled_step() -> None:
    with pytest.raises(pydantic.ValidationError, match="'kernel' was removed: the identifier has one step"):
        IdentifierConfig(kernel="numpy")  # type: ignore[call-arg]  # the removed field is the test
