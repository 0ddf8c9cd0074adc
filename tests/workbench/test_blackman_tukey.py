"""Blackman–Tukey spectra and equivalent bandwidths against analytic references (an AR(1) spectrum, Parseval)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from workbench.experiments.lib.blackman_tukey import blackman_tukey, bt_bandwidth_bins, matched_max_lag, online_bandwidth_bins

N = 256


def test_ar1_spectrum_and_cross_spectrum() -> None:
    """x = AR(1) of unit white noise: S_xx(w) = 1/|1 - a e^-jw|^2; y = x delayed by 3: S_xy = S_xx e^-3jw (transforms of conj(X) Y / L)."""
    rng = np.random.default_rng(0)
    a = 0.6
    x = ss.lfilter([1.0], [1.0, -a], rng.standard_normal(200_000))
    y = np.roll(x, 3)
    spec, count = blackman_tukey(np.vstack([x, y]), [(0, 0), (0, 1)], 0, x.size, 2048, 1024, 64, N)
    assert count == (x.size - 2048) // 1024 + 1
    w = 2 * np.pi * np.fft.rfftfreq(N)
    s_xx = 1.0 / np.abs(1 - a * np.exp(-1j * w)) ** 2
    assert np.max(np.abs(spec[0].real / s_xx - 1)) < 0.1
    assert np.max(np.abs(spec[0].imag)) < 1e-9 * s_xx.max()
    assert np.median(np.abs(spec[1] / (s_xx * np.exp(-3j * w)) - 1)) < 0.1


def test_nothing_fits() -> None:
    with pytest.raises(ValueError, match="no ensemble fits"):
        blackman_tukey(np.zeros((2, 100)), [(0, 1)], 0, 100, 128, 16, 10, N)


@pytest.mark.parametrize("max_lag", [16, 40, 100])
def test_lag_window_bandwidth_is_parsevals(max_lag: int) -> None:
    """Equivalent bandwidth of a lag window w (w[0] = 1) is 1 / Σ w[m]² cycles per sample: N / Σ w² bins."""
    w = ss.get_window(("tukey", 1.0), 2 * max_lag + 3, fftbins=False)[1:-1]  # Tukey alpha 1 = Hann: (1 + cos(pi m / (M + 1))) / 2
    assert bt_bandwidth_bins(max_lag, N) == pytest.approx(N / np.sum(w**2), rel=1e-9)


def test_periodogram_bandwidth_is_parsevals() -> None:
    """|W|² of a window w as a kernel across bins: N (Σ w²)² / Σ r_ww² bins, r_ww the window's autocorrelation."""
    w = ss.get_window("hann", N)
    r = np.correlate(w, w, mode="full")
    assert online_bandwidth_bins(N, 1, 0) == pytest.approx(N * np.sum(w**2) ** 2 / np.sum(r**2), rel=1e-9)
    assert online_bandwidth_bins(N, 17, 2) > online_bandwidth_bins(N, 1, 0)  # smoothing widens it


def test_matched_lag_is_the_closest() -> None:
    target = bt_bandwidth_bins(100, N, oversample=4)
    assert matched_max_lag(target, N) == 100
