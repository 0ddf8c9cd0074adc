"""The compiled step's stages (:mod:`dsp_service.kernel`) against references written here from
their definitions, numpy's complex arithmetic and scipy's peak search.

The step as a whole is held to scipy (csd, savgol_filter, find_peaks) in
test_fast_paths.py and test_scipy_equivalence.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsp_service.identifier import Identifier, IdentifierConfig

from .synth import dataset

N = 512


def test_compiled_step_returns_ordinary_result_objects() -> None:
    """The step builds its PoleEstimate / IdentificationResult without __init__: they must be
    indistinguishable from constructed ones (fields, equality, frozen)."""
    import dataclasses

    _, u, y = dataset(24 * N, seed=3)
    idf = Identifier(IdentifierConfig(fft_width=N))
    for s in range(0, u.shape[1], N // 4):
        idf.push(u[:, s : s + N // 4], y[:, s : s + N // 4])
        r = idf.step()
    assert r.poles
    rebuilt = dataclasses.replace(r, poles=tuple(dataclasses.replace(p) for p in r.poles))
    assert rebuilt == r and [dataclasses.asdict(p) for p in r.poles] == [dataclasses.asdict(p) for p in rebuilt.poles]
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.poles[0].frequency_hz = 1.0  # type: ignore[misc]  # writing the frozen field is the test


def _walk_bin_by_bin(v: np.ndarray, p: int, step: int) -> float:
    """scipy's prominence walk (``_peak_prominences``), one bin at a time."""
    hp, low, j = v[p], v[p], p
    while 0 <= j < v.size and v[j] <= hp:
        low = min(low, v[j])
        j += step
    return float(low)


@pytest.mark.parametrize("size", [3, 15, 16, 17, 33, 404, 809])
def test_the_block_walk_of_the_peak_search_equals_the_walk_bin_by_bin(size: int) -> None:
    """kernel._walk_min crosses whole blocks: the same minimum as the bin-by-bin walk, from every
    start, on rough data, on plateaus (repeated values) and with NaN (a NaN stops the walk)."""
    from dsp_service import kernel

    rng = np.random.default_rng(size)
    cases = [rng.random(size), np.round(rng.random(size) * 4.0) / 4.0, np.sort(rng.random(size))]
    with_nan = rng.random(size)
    with_nan[rng.integers(0, size, 1 + size // 20)] = np.nan
    cases.append(with_nan)
    for v in cases:
        nb = (size + kernel._BLOCK - 1) // kernel._BLOCK
        blocks = [v[q * kernel._BLOCK : (q + 1) * kernel._BLOCK] for q in range(nb)]
        bmin, bmax = np.empty(nb), np.empty(nb)
        kernel._blocks_into(v, bmin, bmax)
        clean = [not np.any(np.isnan(b)) for b in blocks]
        assert [np.isnan(x) for x in bmax] == [not c for c in clean]
        assert all(bmin[q] == b.min() and bmax[q] == b.max() for q, b in enumerate(blocks) if clean[q])
        for p in range(size):
            if np.isnan(v[p]):
                continue
            for step in (-1, 1):
                assert kernel._walk_min(v, bmin, bmax, p, float(v[p]), step) == _walk_bin_by_bin(v, p, step), (p, step)


@pytest.mark.parametrize("n_bins", [1, 4, 5, 6, 7, 257, 1025])
def test_the_averaging_adds_numpys_complex_products(n_bins: int) -> None:
    """kernel._accumulate: ``state[r] += (conj(X_i)·c)·X_j`` for the seven spectra, as numpy's
    complex arithmetic computes it, to 1e-15 of the terms' size (a rounding or two; on x86-64
    with FMA both fuse the same products, and the co-simulation's records, which run through
    this sum, are compared bit for bit); and the power-floor sums ``Σ P11.real``, ``Σ P22.real``
    in bin order. Values over 80 decades, weights from tiny to huge."""
    from dsp_service import kernel

    rng = np.random.default_rng(n_bins)
    X = rng.standard_normal((4, 2 * n_bins)) * np.exp(rng.uniform(-90.0, 90.0, (4, 2 * n_bins)))
    state0 = rng.standard_normal((7, 2 * n_bins)) * np.exp(rng.uniform(-90.0, 90.0, (7, 2 * n_bins)))
    Xc = X.view(np.complex128)
    pairs = [(0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3)]  # SPECTRA_NAMES order
    for c in (1.0, 0.7, 1e-300, 3.3e50, 0.0):
        ours = state0.copy()
        s11, s22 = kernel._accumulate(X, c, ours)
        got = ours.view(np.complex128)
        for r, (i, j) in enumerate(pairs):
            product = (np.conj(Xc[i]) * c) * Xc[j]
            ref = state0.view(np.complex128)[r] + product
            size = np.abs(state0.view(np.complex128)[r]) + np.abs(Xc[i]) * c * np.abs(Xc[j])
            assert np.all(np.abs(got[r] - ref) <= 1e-15 * size), r
        sums = [0.0, 0.0]
        for b in range(n_bins):  # in bin order, one addition at a time
            sums[0] += float(got[0, b].real)
            sums[1] += float(got[4, b].real)
        assert (s11, s22) == tuple(sums)


@pytest.mark.parametrize("w,m", [(17, 404), (17, 23), (9, 100), (3, 8), (1, 37), (31, 250)])
def test_the_smoothing_filter_is_each_windows_sum_in_order(w: int, m: int) -> None:
    """kernel._smooth (the interior as one filter over the (re, im) floats, tap by tap; the edge
    rows one by one) gives each output bin its window's sum in tap order from 0.0, bit for bit;
    and the validity with and without the all-valid shortcut."""
    from dsp_service import kernel

    rng = np.random.default_rng(w * 1000 + m)
    h = w // 2
    k = m + 2 * w + 5
    src = rng.standard_normal(k) + 1j * rng.standard_normal(k)
    lo = 2  # rows 0 … h−1 of the range are edge rows (their own coefficients, start 0)
    centre = rng.standard_normal(w)
    n_edge = min(h, m)
    coef = np.vstack([rng.standard_normal((n_edge, w)), np.tile(centre, (m - n_edge, 1))])
    starts = np.array([0] * n_edge + list(range(1, 1 + m - n_edge)), dtype=np.intp)
    ia, ib = (n_edge, m) if m - n_edge >= 2 else (0, 0)
    for all_valid in (True, False):
        valid = np.ones(k, dtype=bool)
        if not all_valid:
            valid[rng.integers(0, k, 3)] = False
        hs = np.full(m, np.nan + 0j)
        vs = np.zeros(m, dtype=bool)
        n_valid = kernel._smooth(src, valid, lo, lo + m, coef, starts, hs, vs, ia, ib, all_valid)
        for i in range(m):
            a = b = 0.0
            for j in range(w):
                a += float(coef[i, j]) * float(src[starts[i] + j].real)
                b += float(coef[i, j]) * float(src[starts[i] + j].imag)
            assert hs[i].real == a and hs[i].imag == b, i
            assert vs[i] == bool(valid[starts[i] : starts[i] + w].all())
        assert n_valid == int(vs.sum())


@pytest.mark.parametrize("n_max", [1, 2, 5, 16, 17, 40])
def test_the_peak_search_tries_the_maxima_highest_first_and_of_equal_ones_the_later(n_max: int) -> None:
    """kernel._peaks picks the highest untried maximum one at a time (up to _SELECT_MAX maxima)
    or follows a stable sort (more): both the order of scipy's maxima sorted by height, highest
    first, equal heights the later first, with the prominence walk of scipy."""
    from scipy.signal import find_peaks

    from dsp_service import kernel

    rng = np.random.default_rng(n_max)
    size = 8 * n_max + 9
    for trial in range(20):
        mag = np.full(size, 1.0)
        heights = rng.choice([2.0, 3.0, 5.0], n_max) if trial % 2 else rng.uniform(2.0, 9.0, n_max)
        for q, hgt in enumerate(heights):
            mag[8 * q + 4] = hgt  # lone maxima; a dip of depth trial-dependent between them
            mag[8 * q + 8] = 1.0 + 0.05 * rng.integers(0, 3)
        hs = mag.astype(np.complex128)
        want = int(rng.integers(1, n_max + 1))
        ratio = float(rng.choice([1.0001, 2.5, 4.0]))
        v = np.empty(size)
        order, idx, prom = np.zeros(size, dtype=np.intp), np.zeros(want, dtype=np.intp), np.zeros(want)
        nf = kernel._peaks(hs, np.ones(size, dtype=bool), size, np.ones(size), False, ratio, want, v, order, idx, prom, np.empty(size))
        maxima = find_peaks(v)[0]
        ranked = maxima[np.argsort(v[maxima], kind="mergesort")[::-1]]
        expected = []
        for p in ranked:
            base = max(_walk_bin_by_bin(v, int(p), -1), _walk_bin_by_bin(v, int(p), 1))
            if v[p] >= base * ratio:
                expected.append((int(p), 20.0 * math.log10(v[p] / base)))
                if len(expected) == want:
                    break
        if expected:
            assert nf == len(expected)
            assert list(zip(idx[:nf].tolist(), prom[:nf].tolist())) == expected
