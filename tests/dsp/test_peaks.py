"""The vectorised peak search against scipy.signal.find_peaks / peak_prominences (the reference)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal
from hypothesis import given, settings
from hypothesis import strategies as st

from dsp_service.modal import find_modal_peaks, local_maxima, log_weights_db, prominence_bases


def _scipy_prominences(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx, _ = scipy.signal.find_peaks(x)
    if idx.size == 0:
        return idx, np.zeros(0)
    return idx, scipy.signal.peak_prominences(x, idx)[0]


def _ours(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = local_maxima(x)
    xp = np.append(x, np.inf)
    return idx, x[idx] - prominence_bases(xp, x.size, idx)


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
    for x in _spectra(seed):
        idx_ref, prom_ref = _scipy_prominences(x)
        idx, prom = _ours(x)
        np.testing.assert_array_equal(idx, idx_ref)
        np.testing.assert_array_equal(prom, prom_ref)  # the same samples compared: identical


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(-4, 4), min_size=0, max_size=80))
def test_small_integer_sequences_equal_scipy(values: list[int]) -> None:
    """Ties everywhere: plateaus at the ends, plateaus next to plateaus, equal peaks."""
    x = np.asarray(values, dtype=np.float64)
    if x.size < 3:
        assert local_maxima(x).size == 0
        return
    idx_ref, prom_ref = _scipy_prominences(x)
    idx, prom = _ours(x)
    np.testing.assert_array_equal(idx, idx_ref)
    np.testing.assert_array_equal(prom, prom_ref)


def _find_modal_peaks_with_scipy(mag, freqs, weights_db, max_peaks, min_prom):
    """The former implementation of find_modal_peaks (scipy.signal.find_peaks with prominence)."""
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
def test_find_modal_peaks_equals_the_scipy_version(seed: int, max_peaks: int, min_prom: float) -> None:
    rng = np.random.default_rng(100 + seed)
    f = np.asarray(np.fft.rfftfreq(2048, 1 / 200.0)[5:410], dtype=np.float64)  # float64 (the stub says floating)
    mag = 1.0 / np.abs((3.6**2 - f**2) + 0.6j * f) + 0.4 / np.abs((9.0**2 - f**2) + 0.9j * f)
    mag = np.abs(mag * (1.0 + (0.02 + 0.1 * seed / 8) * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size))))
    for weights in (None, log_weights_db(f, 0.5, 0.5)):
        got = find_modal_peaks(mag, f, weights, None, max_peaks, min_prom, refine=False)
        ref = _find_modal_peaks_with_scipy(mag, f, weights, max_peaks, min_prom)
        assert [p.index for p in got] == [r[0] for r in ref]
        np.testing.assert_allclose([p.prominence_db for p in got], [r[1] for r in ref], rtol=0, atol=1e-12)
