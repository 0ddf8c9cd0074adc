"""The off-line recomputation of the DSP's estimate against references: scipy.signal.lfilter/freqz systems, numpy's solve and pinv."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from workbench.experiments.lib.dsp_tf_recompute import COLLINEAR_DET, PAIRS, averaged_spectra, batch_ends, named_tfs, solve_2x2

FS = 200.0
N = 512


def _system(rng: np.random.Generator, n_samples: int) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Two independent white inputs through four IIR paths (y_i = H_i1 u1 + H_i2 u2); channels and the paths' (b, a)."""
    u = rng.standard_normal((2, n_samples))
    paths = {
        "H11": ss.butter(2, 0.2),
        "H21": ss.butter(1, 0.4),
        "H12": ([0.5, 0.25], [1.0]),
        "H22": ss.cheby1(2, 1.0, 0.3),
    }
    y1 = ss.lfilter(*paths["H11"], u[0]) + ss.lfilter(*paths["H21"], u[1])
    y2 = ss.lfilter(*paths["H12"], u[0]) + ss.lfilter(*paths["H22"], u[1])
    return np.vstack([u, y1, y2]), paths


def test_averaged_spectra_and_the_solve_recover_known_paths() -> None:
    """H_jk here is from input k to output j's sum: H11 = u1 -> y1, H12 = u1 -> y2, H21 = u2 -> y1, H22 = u2 -> y2 (the DSP's naming)."""
    channels, paths = _system(np.random.default_rng(1), 60 * N)
    ends = np.arange(N - 1, channels.shape[1], N // 4)
    spectra, freqs, k = averaged_spectra(channels, ends, N, 0.02, FS)
    assert spectra.shape == (len(PAIRS), N // 2 + 1) and k == ends.size
    assert np.allclose(freqs, np.fft.rfftfreq(N, 1 / FS))
    est = named_tfs(spectra, (9, 2))
    band = (freqs > 2.0) & (freqs < 60.0)
    for name, (b, a) in paths.items():
        _, h = ss.freqz(b, a, worN=freqs, fs=FS)
        assert np.median(np.abs(np.abs(est[name][band]) - np.abs(h[band])) / np.abs(h[band])) < 0.05, name
    assert np.allclose(est["Htot"], np.mean([est[n] for n in ("H11", "H12", "H21", "H22")], axis=0))


def test_one_snapshot_is_scipys_csd() -> None:
    channels, _ = _system(np.random.default_rng(2), 4 * N)
    spectra, _, k = averaged_spectra(channels, np.array([N - 1, 2 * N - 1]), N, 1.0, FS)  # alpha 1: the last snapshot only
    assert k == 2
    _, p = ss.csd(channels[0, N : 2 * N], channels[2, N : 2 * N], fs=FS, nperseg=N, noverlap=0, window="hann")
    assert np.allclose(spectra[PAIRS.index((0, 2))], p)


def test_no_full_history_is_refused() -> None:
    with pytest.raises(ValueError, match="no batch with a full history"):
        averaged_spectra(np.zeros((4, 100)), np.array([19, 39]), N, 0.1, FS)


def test_solve_is_numpys_solve_and_collinear_bins_its_truncated_pinv() -> None:
    rng = np.random.default_rng(3)
    m = 64
    a = rng.standard_normal((m, 2)) + 1j * rng.standard_normal((m, 2))
    b = rng.standard_normal((m, 2)) + 1j * rng.standard_normal((m, 2))
    b[: m // 2] = a[: m // 2] * (1 + 1e-3j) + 1e-3 * b[: m // 2]  # nearly collinear inputs in half the bins
    r = rng.standard_normal((m, 2, 2)) + 1j * rng.standard_normal((m, 2, 2))  # r[:, k, j]: cross spectrum of input k and output j
    p = np.empty((m, 2, 2), dtype=complex)
    p[:, 0, 0], p[:, 1, 1] = np.sum(np.abs(a) ** 2, axis=1), np.sum(np.abs(b) ** 2, axis=1)
    p[:, 0, 1] = np.sum(np.conj(a) * b, axis=1)
    p[:, 1, 0] = np.conj(p[:, 0, 1])
    spectra = np.array([p[:, 0, 0], p[:, 0, 1], r[:, 0, 0], r[:, 0, 1], p[:, 1, 1], r[:, 1, 0], r[:, 1, 1]])
    h = solve_2x2(spectra)  # H11, H12, H21, H22: h[j] from input 1, h[2 + j] from input 2, to output j
    det = (p[:, 0, 0] * p[:, 1, 1]).real - np.abs(p[:, 0, 1]) ** 2
    collinear = det < COLLINEAR_DET * (p[:, 0, 0] * p[:, 1, 1]).real
    assert collinear[: m // 2].all() and not collinear[m // 2 :].any()
    for i in range(m):
        pinv = np.linalg.pinv(p[i], rcond=0.1, hermitian=True) if collinear[i] else np.linalg.inv(p[i])
        for j in range(2):
            assert np.allclose([h[j, i], h[2 + j, i]], pinv @ r[i, :, j], rtol=1e-9, atol=0), (i, j)


def test_batch_ends_follow_the_interrupts() -> None:
    irq = np.zeros(200)
    irq[[25, 70, 75]] = 1  # an interrupt late (70 > 39 + 20), one early (75 < 70 + 20)
    assert batch_ends(irq, 20, 200).tolist() == [19, 39, 70, 90]
    assert batch_ends(np.zeros(50), 20, 50).tolist() == [19]
