"""The dominant-direction (rank-1, minimum-norm) solve of collinear bins, against scipy references.

References nobody here wrote: the true responses are ``scipy.signal.freqz`` of the
synthetic system (and of the filter coupling the inputs); the per-input estimate is
checked against ``scipy.signal.csd`` / ``scipy.signal.welch``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from dsp_service.identifier import Identifier, IdentifierConfig
from dsp_service.mimo import MODE_DOMINANT, MODE_FULL, MODE_NONE, MimoSolver

from .synth import FS, dataset, make_system

N = 1024
BATCH = 32
G = (np.array([0.6, 0.3]), np.array([1.0, -0.2]))  # u2 = G(z) u1: dynamic, complex P12


def _run(u: np.ndarray, y: np.ndarray, **cfg: object) -> Identifier:
    idf = Identifier(IdentifierConfig(fft_width=N, averaging="linear", **cfg))
    for s in range(0, u.shape[1], BATCH):
        idf.push(u[:, s : s + BATCH], y[:, s : s + BATCH])
        idf.step()
    return idf


def _collinear_data(n: int = 24 * N, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = ss.lfilter(*ss.butter(4, 40.0, fs=FS), rng.standard_normal(n))
    u = np.vstack([w, ss.lfilter(*G, w) + 1e-5 * rng.standard_normal(n)])
    y = make_system().simulate(u)
    y += 0.01 * y.std(axis=1, keepdims=True) * rng.standard_normal(y.shape)
    return u, y


def test_collinear_inputs_give_the_response_along_the_input_direction() -> None:
    u, y = _collinear_data()
    masked = _run(u, y, collinear="mask").transfer_functions(smoothed=False)
    tf = _run(u, y, collinear="dominant").transfer_functions(smoothed=False)
    f = tf.freqs_hz
    band = (f > 1.0) & (f < 20.0)
    assert not masked.valid[band].any()  # the C40 sees nothing here
    assert tf.mode is not None and np.all(tf.mode[band] == MODE_DOMINANT)
    H = make_system().response(f)
    g = ss.freqz(*G, worN=f, fs=FS)[1]
    for j in range(2):  # Y_j = (H1j + G H2j) U1: what the data identify
        truth = H[j] + g * H[2 + j]
        est = (tf.h11, tf.h12)[j] + g * (tf.h21, tf.h22)[j]
        err = np.abs(est[band] - truth[band]) / np.abs(truth[band])
        assert np.median(err) < 0.02
        assert np.all(np.isfinite(est))


def test_identical_inputs_give_the_exact_total_response() -> None:
    rng = np.random.default_rng(2)
    w = ss.lfilter(*ss.butter(4, 40.0, fs=FS), rng.standard_normal(24 * N))
    u = np.vstack([w, w])
    y = make_system().simulate(u)
    tf = _run(u, y).transfer_functions(smoothed=False)
    f = tf.freqs_hz
    band = (f > 1.0) & (f < 20.0)
    truth = make_system().response(f).mean(axis=0)
    err = np.abs(tf.htot[band] - truth[band]) / np.abs(truth[band])
    assert np.median(err) < 0.01


def test_one_silent_input_gives_the_per_input_estimate() -> None:
    sys_, u, y = dataset(24 * N, seed=3, coupling=0.0)
    u = u.copy()
    u[1] = 0.0
    y = sys_.simulate(u)
    idf = _run(u, y)
    tf = idf.transfer_functions(smoothed=False)
    f = tf.freqs_hz
    band = (f > 1.0) & (f < 20.0)
    assert tf.mode is not None and np.all(tf.mode[band] == MODE_DOMINANT)
    assert np.all(tf.h21[band] == 0) and np.all(tf.h22[band] == 0)  # minimum norm: nothing on the silent input
    # scipy's H1 estimate of the same data: csd(u1, y_j) / welch(u1), same window, segments and detrending
    kw = {"fs": FS, "window": "hann", "nperseg": N, "noverlap": N - BATCH, "detrend": "constant"}
    _, p11 = ss.welch(u[0], **kw)
    for j, est in enumerate((tf.h11, tf.h12)):
        _, p1y = ss.csd(u[0], y[j], **kw)
        ref = p1y / p11
        assert np.median(np.abs(est[band] - ref[band]) / np.abs(ref[band])) < 1e-6


def test_well_conditioned_bins_are_solved_exactly_as_before() -> None:
    _, u, y = dataset(16 * N, seed=4)
    a = _run(u, y, collinear="mask").transfer_functions(smoothed=False)
    b = _run(u, y, collinear="dominant").transfer_functions(smoothed=False)
    assert b.mode is not None and a.mode is not None
    full = b.mode == MODE_FULL
    assert full.mean() > 0.9
    np.testing.assert_array_equal(a.h11[full], b.h11[full])
    np.testing.assert_array_equal(a.htot[full], b.htot[full])
    assert np.all(a.valid[full]) and not np.any(a.valid[b.mode == MODE_DOMINANT])
    assert np.all(b.valid == (b.mode != MODE_NONE))


@pytest.mark.parametrize("segments", [1, 3])
def test_the_steps_total_response_is_the_textbook_solve_per_bin(segments: int) -> None:
    """The step's ``H_tot`` (the compiled solve on the bins it searches) against numpy's linear
    algebra bin by bin: ``H = P⁻¹ R`` (``np.linalg.solve``) on the fully solved bins, the
    dominant eigenvector of ``P`` (``np.linalg.eigh``) on the collinear ones, to 1e-9 (the
    2×2 solve of bins near the determinant threshold, condition number up to 1e3); on the
    snapshot's spectra (the compiled averaging) and on the segmented ones (Welch within the
    history, averaged before the compiled solve)."""
    _, u_full, y_full = dataset(8 * N, seed=5)
    checked = {MODE_FULL: 0, MODE_DOMINANT: 0}
    for u, y in (_collinear_data(8 * N, seed=5), (u_full, y_full)):
        idf = _run(u, y, welch_segments=segments)
        S, sl = idf._avg.state, idf._sl
        got, mode = idf._solver.source[sl], idf._solver.mode[sl]
        for k, m in zip(range(sl.start, sl.stop), mode):
            P = np.array([[S[0, k], S[1, k]], [np.conj(S[1, k]), S[4, k]]])
            R = np.array([[S[2, k], S[3, k]], [S[5, k], S[6, k]]])  # rows P_iy1, P_iy2
            if m == MODE_FULL:
                H = np.linalg.solve(P, R)
            else:
                assert m == MODE_DOMINANT
                sigma, vecs = np.linalg.eigh(P)
                v = vecs[:, 1]
                H = np.outer(v, np.conj(v) @ R) / sigma[1]
            ref = H.mean()
            assert abs(got[k - sl.start] - ref) <= 1e-9 * abs(ref), k
            checked[int(m)] += 1
    assert min(checked.values()) >= 100


# ---------------------------------------------------------------------------
# Welch within the history (welch_segments > 1), against scipy.signal.csd
# ---------------------------------------------------------------------------
@pytest.mark.parametrize("segments", [3, 7])
def test_segmented_spectra_equal_scipy_csd_with_zero_padding(segments: int) -> None:
    _, u, y = dataset(N, seed=6)
    idf = Identifier(IdentifierConfig(fft_width=N, welch_segments=segments, averaging="linear"))
    idf.push(u, y)
    idf.step()
    L = 2 * N // (segments + 1)
    kw = {"fs": FS, "window": "hann", "nperseg": L, "noverlap": L // 2, "nfft": N, "detrend": "constant"}
    sp = idf.spectra("density")
    x = {"1": u[0], "2": u[1], "y1": y[0], "y2": y[1]}
    for name, (a, b) in {"P11": ("1", "1"), "P12": ("1", "2"), "P1y1": ("1", "y1"), "P2y2": ("2", "y2")}.items():
        _, ref = ss.csd(x[a], x[b], **kw)
        np.testing.assert_allclose(sp[name], ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max())
    assert idf.effective_averages > 0.9 * segments


def test_segmented_averaging_cuts_the_error_of_correlated_inputs() -> None:
    """N 1024, α 0.1, l 20 (≈ 1.35 effective averages) against 7 segments per snapshot, inputs ρ ≈ 0.7.

    A well-damped system (ζ 0.3), whose impulse response is short against the 256-sample
    segments: the segments' variance reduction shows without their resolution bias
    (which, near a lightly damped peak, they add: see docs/identification.md).
    """
    from .synth import RESIDUES, correlated_inputs

    sys_ = make_system(modes=((3.6, 0.3), (9.0, 0.3)), residues=RESIDUES)
    u = correlated_inputs(8 * N, seed=7, coupling=0.9)
    y = sys_.simulate(u)
    y += 0.05 * y.std(axis=1, keepdims=True) * np.random.default_rng(8).standard_normal(y.shape)
    errs = {}
    for segs in (1, 7):
        idf = Identifier(IdentifierConfig(fft_width=N, welch_segments=segs, smoothing_window=0))
        for s in range(0, u.shape[1], 20):
            idf.push(u[:, s : s + 20], y[:, s : s + 20])
            idf.step()
        tf = idf.transfer_functions(smoothed=False)
        f = tf.freqs_hz
        band = (f > 1.0) & (f < 15.0)
        H = sys_.response(f)
        est = np.array([tf.h11, tf.h12, tf.h21, tf.h22])
        errs[segs] = float(np.median(np.abs(est[:, band] - H[:, band]) / np.abs(H[:, band])))
        if segs == 7:
            assert idf.effective_averages > 5.0
    assert errs[7] < 0.85 * errs[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_the_downloads_solve_is_the_textbook_solve_per_bin(seed: int) -> None:
    """``MimoSolver.solve`` (the compiled solve of every bin the downloads use) against numpy's
    linear algebra on spectra with full-rank, collinear and silent bins: ``np.linalg.solve`` where
    the 2×2 is well conditioned (tests/dsp/references.py, the same mask), ``np.linalg.eigh``'s
    dominant eigenvector on the collinear bins, 0 on the silent ones; to 1e-9 relative."""
    from .references import mimo_solve

    rng = np.random.default_rng(seed)
    k, snaps = 257, 40
    X = rng.standard_normal((snaps, 4, k)) + 1j * rng.standard_normal((snaps, 4, k))
    X[:, 1, ::5] = (0.7 - 0.4j) * X[:, 0, ::5]  # collinear inputs every fifth bin
    X[:, 0:2, 3] = 0.0  # one silent bin
    pairs = [(0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)]
    S = np.array([np.mean(np.conj(X[:, i]) * X[:, j], axis=0) for i, j in pairs])
    solver = MimoSolver(k, "mimo", 1e-3, 1e-12, "dominant")
    H, valid = solver.solve(S)
    H_ref, full = mimo_solve(S, 1e-3, 1e-12)
    assert full.sum() > 150 and np.array_equal(solver.mode == MODE_FULL, full)
    np.testing.assert_allclose(H[:, full], H_ref[:, full], rtol=1e-9)
    collinear = solver.mode == MODE_DOMINANT
    assert collinear.sum() >= 40 and not valid[3] and np.all(H[:, 3] == 0)
    for b in np.flatnonzero(collinear):
        P = np.array([[S[0, b], S[1, b]], [np.conj(S[1, b]), S[4, b]]])
        R = np.array([[S[2, b], S[3, b]], [S[5, b], S[6, b]]])
        sigma, vecs = np.linalg.eigh(P)
        v = vecs[:, 1]
        h = np.outer(v, np.conj(v) @ R) / sigma[1]
        np.testing.assert_allclose(H[:, b], [h[0, 0], h[0, 1], h[1, 0], h[1, 1]], rtol=1e-9)
