"""§4.1.1 equivalent: our FFTs, power spectra and H estimates equal an independent scipy computation."""

from __future__ import annotations

from typing import Literal

import numpy as np
import pytest
import scipy.signal

from dsp_service.identifier import Identifier, IdentifierConfig
from dsp_service.spectra import SPECTRA_NAMES

FS = 200.0
N = 512
PAIRS = {  # our name -> (x, y) channel indices for scipy.signal.csd(x, y)
    "P11": (0, 0),
    "P12": (0, 1),
    "P1y1": (0, 2),
    "P1y2": (0, 3),
    "P22": (1, 1),
    "P2y1": (1, 2),
    "P2y2": (1, 3),
    "P21": (1, 0),
}


def _data(n: int, seed: int = 7) -> np.ndarray:
    """Four channels u1, u2, y1, y2 with correlated inputs, DC offsets and dynamics."""
    rng = np.random.default_rng(seed)
    w = rng.standard_normal((4, n))
    u1 = w[0] + 3.0
    u2 = 0.6 * np.roll(w[0], 2) + 0.8 * w[1] - 1.5
    b, a = scipy.signal.butter(2, 0.1)
    y1 = scipy.signal.lfilter(b, a, u1) + 0.3 * u2 + 0.05 * w[2] + 10.0
    y2 = scipy.signal.lfilter(b, a, u2) - 0.2 * u1 + 0.05 * w[3]
    return np.vstack([u1, u2, y1, y2])


def _corrected_solve(P: dict[str, np.ndarray]) -> np.ndarray:
    """Independent textbook implementation of the corrected [2-21 … 2-24]."""
    den = P["P11"] * P["P22"] - P["P12"] * P["P21"]
    return np.array(
        [
            (P["P1y1"] * P["P22"] - P["P12"] * P["P2y1"]) / den,
            (P["P1y2"] * P["P22"] - P["P12"] * P["P2y2"]) / den,
            (P["P2y1"] * P["P11"] - P["P21"] * P["P1y1"]) / den,
            (P["P2y2"] * P["P11"] - P["P21"] * P["P1y2"]) / den,
        ]
    )


def test_single_snapshot_ffts_and_raw_spectra_match_scipy() -> None:
    """One snapshot through the identifier's compiled detrend and averaging (α = 1: the averages
    are that snapshot's spectra) against scipy's detrended, windowed FFTs and csd."""
    x = _data(N)
    idf = Identifier(IdentifierConfig(fft_width=N, alpha=1.0, smoothing_window=0))
    idf.push(x[:2], x[2:])
    idf.step()
    est = idf._est
    raw = idf.spectra("raw")
    win = scipy.signal.get_window("hann", N)
    ref_fft = np.fft.rfft(scipy.signal.detrend(x, type="constant", axis=-1) * win, axis=-1)
    np.testing.assert_allclose(est.ffts, ref_fft, rtol=0, atol=1e-11 * np.abs(ref_fft).max())
    scale = est.scale_factor("spectrum")
    for name in SPECTRA_NAMES:
        a, b = PAIRS[name]
        _, ref = scipy.signal.csd(
            x[a],
            x[b],
            fs=FS,
            window="hann",
            nperseg=N,
            noverlap=0,
            detrend="constant",
            scaling="spectrum",
        )
        ours = raw[name] * scale
        ours[1:-1] *= 2.0
        np.testing.assert_allclose(ours, ref, rtol=1e-10, atol=1e-12 * np.abs(ref).max())


@pytest.mark.parametrize("scaling", ["density", "spectrum"])
def test_welch_averaged_spectra_and_h_match_scipy(scaling: Literal["density", "spectrum"]) -> None:
    segments = 12
    x = _data(N + (segments - 1) * (N // 2))
    idf = Identifier(IdentifierConfig(fft_width=N, averaging="linear", smoothing_window=0))
    idf.push(x[:2, :N], x[2:, :N])
    idf.step()
    for s in range(N, x.shape[1], N // 2):
        idf.push(x[:2, s : s + N // 2], x[2:, s : s + N // 2])
        idf.step()
    assert idf.effective_averages == pytest.approx(segments)
    ours = idf.spectra(scaling)
    ref: dict[str, np.ndarray] = {}
    for name, (a, b) in PAIRS.items():
        freqs, ref[name] = scipy.signal.csd(
            x[a],
            x[b],
            fs=FS,
            window="hann",
            nperseg=N,
            noverlap=N // 2,
            detrend="constant",
            scaling=scaling,
        )
        np.testing.assert_allclose(ours[name], ref[name], rtol=1e-10, atol=1e-12 * np.abs(ref[name]).max(), err_msg=name)
    # auto spectra equal welch (real)
    _, p11 = scipy.signal.welch(x[0], fs=FS, nperseg=N, scaling=scaling)
    np.testing.assert_allclose(ours["P11"].real, p11, rtol=1e-10)
    # transfer functions: ours (mimo, unsmoothed) vs the independent solve on scipy's spectra
    tf = idf.transfer_functions(smoothed=False)
    np.testing.assert_allclose(tf.freqs_hz, freqs)
    H_ref = _corrected_solve(ref)
    valid = tf.valid
    assert valid[1:-1].all()
    for i, h in enumerate((tf.h11, tf.h12, tf.h21, tf.h22)):
        np.testing.assert_allclose(h[valid], H_ref[i][valid], rtol=1e-9)
    np.testing.assert_allclose(tf.htot[valid], H_ref.mean(axis=0)[valid], rtol=1e-9)
    # the step's own H_tot (the compiled solve on the bins it searches) against the same reference
    sl = idf._sl
    step_valid = idf._solver.valid[sl]
    assert step_valid.all()
    np.testing.assert_allclose(idf._solver.source[sl], H_ref.mean(axis=0)[sl], rtol=1e-9)
