"""The compiled step's peak search (:func:`dsp_service.kernel._peaks`) against
scipy.signal.find_peaks / peak_prominences (the reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from dsp_service import kernel
from dsp_service.modal import log_weights


def log_weights_db(freqs: np.ndarray, f_ref: float, exponent: float) -> np.ndarray:
    return 20.0 * np.log10(log_weights(freqs, f_ref, exponent))


def kernel_peaks(
    mag: np.ndarray, weights: np.ndarray | None = None, valid: np.ndarray | None = None, want: int | None = None, min_prom_db: float = 0.0
) -> list[tuple[int, float]]:
    """``(index, prominence dB)`` of the best ``want`` peaks of ``mag·weights`` by the compiled search."""
    size = mag.size
    want = size if want is None else want
    vs = np.ones(size, dtype=bool) if valid is None else valid
    w = np.ones(size) if weights is None else weights
    idx, prom = np.zeros(want, dtype=np.intp), np.zeros(want)
    nf = kernel._peaks(
        mag.astype(np.complex128),
        vs,
        int(vs.sum()),
        w,
        weights is not None,
        10.0 ** (min_prom_db / 20.0),
        want,
        np.empty(size),
        np.zeros(size, dtype=np.intp),
        idx,
        prom,
        np.empty(size + 2 * kernel._BLOCK),
    )
    return list(zip(idx[:nf].tolist(), prom[:nf].tolist()))


def _scipy_prominences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx, _ = scipy.signal.find_peaks(x)
    if idx.size == 0:
        return idx, np.zeros(0)
    return idx, scipy.signal.peak_prominences(x, idx)[0]


def _ours(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every local maximum of ``v`` (> 0) and its prominence in dB, in index order."""
    found = sorted(kernel_peaks(v))
    return np.array([p for p, _ in found], dtype=np.intp), np.array([q for _, q in found])


def _spectra(seed: int) -> list[np.ndarray]:
    """Random, smoothed, resonant, quantised (plateaus) and masked-like (flat runs) test arrays."""
    rng = np.random.default_rng(seed)
    f = np.linspace(0.5, 40.0, 404)
    res = 1.0 / np.abs((3.6**2 - f**2) + 0.6j * f) + 0.4 / np.abs((9.0**2 - f**2) + 0.9j * f)
    noisy = res * (1.0 + 0.05 * rng.standard_normal(f.size))
    smooth = scipy.signal.savgol_filter(noisy, 17, 2)
    quant = np.round(rng.standard_normal(300) * 2.0)  # many plateaus, some at the ends
    masked = 20 * np.log10(noisy)
    masked[100:140] = masked.min()  # a run at the minimum, as masked bins are filled
    masked[200:203] = masked[199] + 1.0  # a plateau peak
    return [
        rng.standard_normal(150),  # ~50 maxima: the pairwise path at its busiest
        rng.standard_normal(500),
        rng.standard_normal(5000),  # > 64 maxima: the scipy fallback of the prominence bases
        noisy,
        smooth,
        20 * np.log10(smooth) + log_weights_db(f, 0.5, 0.5),
        quant,
        np.repeat(rng.standard_normal(60), rng.integers(1, 4, 60)),
        masked,
        np.ones(50),
        np.linspace(0, 1, 50),
        np.array([0.0, 1.0, 1.0]),
        np.array([0.0, 1.0, 1.0, 0.5]),
        np.array([1.0, 1.0, 0.0, 2.0, 2.0, 2.0, 1.0, 3.0, 3.0]),
    ]


@pytest.mark.parametrize("seed", range(6))
def test_local_maxima_and_prominences_equal_scipy(seed: int) -> None:
    """On ``v = 10^(x/20)`` the search's maxima are scipy's on ``x`` and its prominences in dB
    scipy's prominences of ``x`` (to 1e-9 dB: the logarithm's rounding)."""
    for x in _spectra(seed):
        idx_ref, prom_ref = _scipy_prominences(x)
        if x.size < 3 or idx_ref.size == 0:
            continue
        idx, prom = _ours(10.0 ** (x / 20.0))
        np.testing.assert_array_equal(idx, idx_ref)
        np.testing.assert_allclose(prom, prom_ref, rtol=0, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-4, 4), min_size=3, max_size=80))
def test_small_integer_sequences_equal_scipy(values: list[int]) -> None:
    """Ties everywhere: plateaus at the ends, plateaus next to plateaus, equal peaks (``v = 2^x``:
    exact, so equal samples stay equal)."""
    x = np.asarray(values, dtype=np.float64)
    idx_ref, prom_ref = _scipy_prominences(x)
    if idx_ref.size == 0:
        return
    idx, prom = _ours(2.0**x)
    np.testing.assert_array_equal(idx, idx_ref)
    np.testing.assert_allclose(prom / (20.0 * math.log10(2.0)), prom_ref, rtol=0, atol=1e-12)


def _find_modal_peaks_with_scipy(mag, weights_db, max_peaks, min_prom):
    """The search written with scipy.signal.find_peaks with prominence."""
    wdb = 20.0 * np.log10(np.maximum(mag, np.finfo(np.float64).tiny))
    if weights_db is not None:
        wdb = wdb + weights_db
    idx, props = scipy.signal.find_peaks(wdb, prominence=min_prom)
    if idx.size == 0:
        g = int(np.argmax(wdb))
        if g == 0 or g == wdb.size - 1:
            return []
        return [(g, float(scipy.signal.peak_prominences(wdb, [g])[0][0]))]
    order = np.argsort(wdb[idx])[::-1][:max_peaks]
    return [(int(idx[o]), float(props["prominences"][o])) for o in order]


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("max_peaks,min_prom", [(2, 3.0), (4, 0.5), (1, 20.0), (6, 0.0)])
def test_the_best_peaks_are_scipys(seed: int, max_peaks: int, min_prom: float) -> None:
    rng = np.random.default_rng(100 + seed)
    f = np.asarray(np.fft.rfftfreq(2048, 1 / 200.0)[5:410], dtype=np.float64)
    mag = 1.0 / np.abs((3.6**2 - f**2) + 0.6j * f) + 0.4 / np.abs((9.0**2 - f**2) + 0.9j * f)
    mag = np.abs(mag * (1.0 + (0.02 + 0.1 * seed / 8) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))))
    for weights in (None, log_weights(f, 0.5, 0.5)):
        got = kernel_peaks(mag, weights, want=max_peaks, min_prom_db=min_prom)
        ref = _find_modal_peaks_with_scipy(mag, None if weights is None else 20.0 * np.log10(weights), max_peaks, min_prom)
        assert [p for p, _ in got] == [r[0] for r in ref]
        np.testing.assert_allclose([q for _, q in got], [r[1] for r in ref], rtol=0, atol=1e-9)


def test_log_weighting_prefers_the_lower_of_two_equal_peaks() -> None:
    f = np.asarray(np.fft.rfftfreq(2048, 1 / 200.0)[5:410], dtype=np.float64)
    df = f[1] - f[0]
    mag = np.exp(-0.5 * ((f - 4.0) / 0.2) ** 2) + 1.01 * np.exp(-0.5 * ((f - 4.6) / 0.2) ** 2) + 0.05
    plain = kernel_peaks(mag, want=2, min_prom_db=3.0)
    weighted = kernel_peaks(mag, log_weights(f, 0.5, 0.5), want=2, min_prom_db=3.0)
    assert len(plain) == len(weighted) == 2
    assert f[plain[0][0]] == pytest.approx(4.6, abs=df)  # unweighted: the higher one
    assert f[weighted[0][0]] == pytest.approx(4.0, abs=df)  # weighted: the lower one
    assert f[weighted[1][0]] == pytest.approx(4.6, abs=df)  # both split poles reported


def test_peak_search_respects_mask_and_edges() -> None:
    f = np.linspace(0.5, 40.0, 405)
    mag = np.exp(-0.5 * ((f - 4.0) / 0.2) ** 2) + 0.05
    assert kernel_peaks(mag, valid=np.zeros(f.size, dtype=bool), want=2, min_prom_db=3.0) == []
    rising = np.linspace(1.0, 2.0, f.size)  # no interior maximum
    assert kernel_peaks(rising, want=2, min_prom_db=3.0) == []
    masked = np.ones(f.size, dtype=bool)
    masked[150:170] = False  # a high spike among masked bins is not a peak
    spiky = mag.copy()
    spiky[160] = 10.0
    assert [p for p, _ in kernel_peaks(spiky, valid=masked, want=2, min_prom_db=3.0)] == [int(np.argmax(mag))]
