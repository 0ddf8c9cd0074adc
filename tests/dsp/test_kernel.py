"""The compiled step (``kernel='numba'``, :mod:`dsp_service.kernel`) equals the numpy reference.

Both identifiers see the same batches; every output the Identifier returns
(poles with frequency, damping, magnitude, prominence and confidence, the
valid fraction, and the downloads: transfer functions, valid mask and mode)
must agree to 1e-12 relative (sums are taken in a different order).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as ss

from dsp_service.identifier import Identifier, IdentifierConfig

from .synth import FS, dataset, make_system

N = 512
RTOL = 1e-12
_POLE_FIELDS = (
    "frequency_hz",
    "damping_ratio",
    "damping_fwhm",
    "damping_vrm",
    "natural_frequency_vrm_hz",
    "magnitude",
    "prominence_db",
    "confidence",
    "damping_fit",
    "damping_defined",
    "source",
)


def _close(a: object, b: object) -> bool:
    if a is None or b is None or isinstance(a, (bool, str)):
        return a == b
    assert isinstance(a, float) and isinstance(b, float)
    return math.isclose(a, b, rel_tol=RTOL, abs_tol=1e-300)


def _collinear(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = ss.lfilter(*ss.butter(4, 40.0, fs=FS), rng.standard_normal(n))
    u = np.vstack([w, 0.7 * w + 1e-5 * rng.standard_normal(n)])
    y = make_system().simulate(u)
    y += 0.01 * y.std(axis=1, keepdims=True) * rng.standard_normal(y.shape)
    return u, y


def _compare(cfg: dict, u: np.ndarray, y: np.ndarray, batch: int) -> int:
    ref = Identifier(IdentifierConfig(fft_width=N, kernel="numpy", **cfg))
    fast = Identifier(IdentifierConfig(fft_width=N, kernel="numba", **cfg))
    assert fast._fused
    poles = 0
    for s in range(0, u.shape[1], batch):
        for idf in (ref, fast):
            idf.push(u[:, s : s + batch], y[:, s : s + batch])
        a, b = ref.step(), fast.step()
        assert len(a.poles) == len(b.poles), s
        for name in ("confidence", "valid_fraction", "effective_averages"):
            assert _close(getattr(a, name), getattr(b, name)), (s, name)
        assert a.samples_in_history == b.samples_in_history
        for pa, pb in zip(a.poles, b.poles):
            for f in _POLE_FIELDS:
                assert _close(getattr(pa, f), getattr(pb, f)), (s, f, getattr(pa, f), getattr(pb, f))
        poles += len(a.poles)
        if s % (8 * batch) == 0:
            for smoothed in (True, False):
                ta, tb = ref.transfer_functions(smoothed), fast.transfer_functions(smoothed)
                np.testing.assert_array_equal(ta.valid, tb.valid)
                np.testing.assert_array_equal(ta.mode, tb.mode)
                for f in ("h11", "h12", "h21", "h22", "htot"):
                    x, z = getattr(ta, f), getattr(tb, f)
                    np.testing.assert_allclose(z, x, rtol=RTOL, atol=RTOL * max(np.abs(x).max(), 1e-300))
    return poles


@pytest.mark.parametrize(
    "cfg",
    [
        {},
        {"averaging": "linear"},
        {"alpha": 1.0},
        {"wait_for_full_history": False},
        {"smoothing_window": 0},
        {"smoothing_window": 9, "smoothing_order": 3},
        {"log_weighting": False, "max_peaks": 4},
        {"estimate_on_smoothed": True},
        {"damping_method": "fwhm", "fwhm_exact": False},
        {"damping_method": "fit"},
        {"damping_method": "transient"},
        {"min_peak_prominence_db": 40.0},
        {"search_min_hz": 0.0, "search_max_hz": 100.0},
        {"det_threshold": 0.5},
        {"smoothing_window": 0, "min_peak_prominence_db": 8.0},  # many low maxima
        {"smoothing_window": 0, "max_peaks": 16, "min_peak_prominence_db": 1.0},
    ],
)
def test_compiled_step_equals_the_numpy_reference(cfg: dict) -> None:
    _, u, y = dataset(24 * N, seed=3)
    assert _compare(cfg, u, y, N // 8) > 0


@pytest.mark.parametrize("collinear", ["dominant", "mask"])
def test_compiled_step_equals_the_reference_on_collinear_inputs(collinear: str) -> None:
    u, y = _collinear(24 * N)
    _compare({"collinear": collinear, "averaging": "linear"}, u, y, N // 8)


def test_compiled_step_masks_a_silent_input_like_the_reference() -> None:
    _, u, y = dataset(16 * N, seed=1)
    u = u.copy()
    u[1, 4 * N :] = 0.0
    _compare({}, u, y, N // 4)


def test_other_settings_fall_back_to_the_numpy_path() -> None:
    for cfg in ({"welch_segments": 3}, {"averaging": "rls"}, {"solver": "uncorrelated"}, {"peak_source": "11"}):
        assert not Identifier(IdentifierConfig(kernel="numba", **cfg))._fused


def test_compiled_step_returns_ordinary_result_objects() -> None:
    """The fused step builds its PoleEstimate / IdentificationResult without __init__: they must be
    indistinguishable from constructed ones (fields, equality, frozen)."""
    import dataclasses

    _, u, y = dataset(24 * N, seed=3)
    idf = Identifier(IdentifierConfig(fft_width=N, kernel="numba"))
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
        bmin, bmax = kernel._blocks(v)
        clean = [not np.any(np.isnan(b)) for b in blocks]
        assert [np.isnan(x) for x in bmax] == [not c for c in clean]
        assert all(bmin[q] == b.min() and bmax[q] == b.max() for q, b in enumerate(blocks) if clean[q])
        for p in range(size):
            if np.isnan(v[p]):
                continue
            for step in (-1, 1):
                assert kernel._walk_min(v, bmin, bmax, p, float(v[p]), step) == _walk_bin_by_bin(v, p, step), (p, step)


@pytest.mark.parametrize("n_bins", [1, 4, 5, 6, 7, 257, 1025])
def test_the_vector_averaging_is_the_scalar_loop_bit_for_bit(n_bins: int) -> None:
    """kernel._accumulate (four bins of all seven spectra per vector step, the power-floor sums
    in the same loop) equals its scalar definition, ``state[r] += (conj(X_i)·c)·X_j`` bin by bin
    with numpy's fused multiply-adds and the sums in bin order, to the bit: every K mod 4, values
    over 80 decades, weights from tiny to huge."""
    from numba import njit

    from dsp_service import kernel

    fma = kernel._fma

    @njit
    def scalar(X: np.ndarray, c: float, state: np.ndarray) -> tuple[float, float]:
        k = X.shape[1] // 2
        for r in range(7):
            i, j = (0, r) if r < 4 else (1, r - 3)
            for b in range(k):
                ur = X[i, 2 * b] * c
                ui = -X[i, 2 * b + 1] * c
                br, bi = X[j, 2 * b], X[j, 2 * b + 1]
                state[r, 2 * b] += fma(ur, br, -(ui * bi))
                state[r, 2 * b + 1] += fma(ur, bi, ui * br)
        s11 = s22 = 0.0
        for b in range(k):
            s11 += state[0, 2 * b]
            s22 += state[4, 2 * b]
        return s11, s22

    rng = np.random.default_rng(n_bins)
    X = rng.standard_normal((4, 2 * n_bins)) * np.exp(rng.uniform(-90.0, 90.0, (4, 2 * n_bins)))
    state0 = rng.standard_normal((7, 2 * n_bins)) * np.exp(rng.uniform(-90.0, 90.0, (7, 2 * n_bins)))
    for c in (1.0, 0.7, 1e-300, 3.3e50, 0.0):
        ours, ref = state0.copy(), state0.copy()
        sums = kernel._accumulate(X, c, ours)
        assert sums == scalar(X, c, ref)
        assert np.array_equal(ours.view(np.int64), ref.view(np.int64))


@pytest.mark.parametrize("w,m", [(17, 404), (17, 23), (9, 100), (3, 8), (1, 37), (31, 250)])
def test_the_smoothing_filter_is_each_windows_sum_in_order(w: int, m: int) -> None:
    """kernel._smooth (the interior as one filter over the (re, im) floats, sixteen at a time;
    the edge rows one by one) gives each output bin its window's sum in tap order from 0.0,
    bit for bit, whatever m and w leave for the scalar remainder; and the validity with and
    without the all-valid shortcut."""
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
    from scipy.signal._peak_finding_utils import _local_maxima_1d

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
        maxima = np.asarray(_local_maxima_1d(v)[0])
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
