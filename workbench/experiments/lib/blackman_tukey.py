"""Correlation-based (Blackman–Tukey) cross spectra and the equivalent bandwidth of spectral windows (thesis §4.1.2).

:func:`blackman_tukey` averages, over evenly spaced ensembles, the transforms
of the biased auto/cross-correlations under a Tukey–Hanning lag window; the
bandwidth functions say how wide a spectral window is in bins, so that a lag
window can be matched (:func:`matched_max_lag`) to the on-line estimate's
Hann periodogram followed by its Savitzky–Golay smoother
(:func:`online_bandwidth_bins`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import scipy.signal as ss


def blackman_tukey(
    channels: np.ndarray, pairs: Sequence[tuple[int, int]], start: int, stop: int, ensemble: int, hop: int, max_lag: int, nfft: int
) -> tuple[np.ndarray, int]:
    """Averaged Blackman–Tukey spectra (len(pairs), nfft//2+1) of ensembles of ``ensemble`` samples every ``hop`` in ``[start, stop)``.

    ``r_ab[m] = (1/L) Σ_t a[t] b[t+m]`` (biased, mean removed per ensemble),
    so its transform is ``conj(A)·B / L`` like a periodogram's cross spectrum;
    Tukey–Hanning lag window ``(1 + cos(π m / (M + 1))) / 2``, ``|m| ≤ M``.
    Returns the spectra and the number of ensembles; ``ValueError`` when none fits.
    """
    lags = np.arange(-max_lag, max_lag + 1)
    lag_window = 0.5 * (1.0 + np.cos(np.pi * lags / (max_lag + 1)))
    acc = np.zeros((len(pairs), nfft // 2 + 1), dtype=complex)
    count = 0
    for s in range(start, stop - ensemble + 1, hop):
        x = channels[:, s : s + ensemble]
        x = x - x.mean(axis=1, keepdims=True)
        spec = np.fft.fft(x, 2 * ensemble, axis=1)
        for i, (a, b) in enumerate(pairs):
            r = np.fft.ifft(np.conj(spec[a]) * spec[b]).real / ensemble
            buf = np.zeros(nfft)
            buf[: max_lag + 1] = r[: max_lag + 1] * lag_window[max_lag:]
            buf[nfft - max_lag :] = r[-max_lag:] * lag_window[:max_lag]
            acc[i] += np.fft.rfft(buf)
        count += 1
    if count == 0:
        raise ValueError("no ensemble fits the stretch")
    return acc / count, count


def _bandwidth(kernel: np.ndarray, oversample: int) -> float:
    """Equivalent bandwidth ``(Σ K)² / Σ K²`` of a spectral smoothing kernel sampled ``oversample`` times per bin, in bins."""
    return float(kernel.sum() ** 2 / np.sum(kernel**2) / oversample)


def online_bandwidth_bins(n: int, sg_window: int, sg_order: int, oversample: int = 8) -> float:
    """Equivalent bandwidth (bins) of a Hann periodogram of ``n`` samples smoothed across bins by Savitzky–Golay.

    The Hann window's |W|² convolved with the Savitzky–Golay coefficients
    (``scipy.signal.savgol_coeffs``), sampled ``oversample`` times per bin.
    """
    w = ss.get_window("hann", n)
    kern = np.fft.fftshift(np.abs(np.fft.fft(w, n * oversample)) ** 2)
    if sg_window > 1:
        fine = np.zeros(sg_window * oversample)
        fine[::oversample] = ss.savgol_coeffs(sg_window, sg_order)
        kern = np.convolve(kern, fine)
    return _bandwidth(kern, oversample)


def bt_bandwidth_bins(max_lag: int, n: int, oversample: int = 8) -> float:
    """Equivalent bandwidth (bins of an ``n``-point grid) of the Tukey–Hanning lag window of ``max_lag`` lags."""
    m = np.arange(-max_lag, max_lag + 1)
    lag_window = 0.5 * (1.0 + np.cos(np.pi * m / (max_lag + 1)))
    buf = np.zeros(n * oversample)
    buf[: max_lag + 1] = lag_window[max_lag:]
    buf[-max_lag:] = lag_window[:max_lag]
    return _bandwidth(np.fft.fft(buf).real, oversample)


def matched_max_lag(bandwidth_bins: float, n: int) -> int:
    """The Tukey–Hanning max lag (16 to n/2 in steps of 4) whose equivalent bandwidth is closest to ``bandwidth_bins``."""
    lags = np.arange(16, n // 2 + 1, 4)
    bw = np.array([bt_bandwidth_bins(int(m), n, oversample=4) for m in lags])
    return int(lags[np.argmin(np.abs(bw - bandwidth_bins))])
