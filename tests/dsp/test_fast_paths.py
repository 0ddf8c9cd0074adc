"""The identifier's hot path against references built here from public building blocks: numpy's
FFT and linear algebra, scipy.signal's savgol_filter, find_peaks and peak_prominences, the VRM
triplets one by one (tests/dsp/references.py)."""

from __future__ import annotations

import math
from itertools import combinations
from typing import Literal

import numpy as np
import pytest
import scipy.signal

from dsp_service.identifier import Identifier, IdentifierConfig
from dsp_service.modal import VrmEstimator
from dsp_service.spectra import rfft_rows

from .references import c12_corrected, half_power_crossings, mimo_solve, parabola_vertex, zeta_from_half_power_width
from .synth import dataset

FS, N = 200.0, 2048
FREQS = np.asarray(np.fft.rfftfreq(N, 1.0 / FS), dtype=np.float64)  # float64 (the stub says floating)


# ------------------------------------------------------------------- spectra
def test_rfft_rows_is_numpys_rfft() -> None:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((4, 512))
    np.testing.assert_array_equal(rfft_rows(x), np.fft.rfft(x, axis=-1))
    out = np.empty((4, 257), dtype=np.complex128)
    assert rfft_rows(x, out) is out
    np.testing.assert_array_equal(out, np.fft.rfft(x, axis=-1))
    np.testing.assert_array_equal(rfft_rows(x[1]), np.fft.rfft(x[1]))


# ---------------------------------------------------------------------- VRM
def _vrm_band(est: VrmEstimator, n: int, k: int, half_width: float, valid: np.ndarray | None) -> tuple[int, int] | None:
    """``(m, stride)`` of the estimator's band (its doc): ``h = round(band_factor × half-width)`` bins
    each side within the array and short of any invalid bin, at most ``m_max`` points each side."""
    h = min(max(1, round(est.band_factor * half_width)), k, n - 1 - k)
    if h >= 1 and valid is not None:
        bad = [abs(i - k) - 1 for i in range(k - h, k + h + 1) if not valid[i]]
        h = min([h, *bad])
    if h < 1:
        return None
    m = min(h, est.m_max)
    stride = max(1, round(h / m))
    return (h // stride if m * stride > h else m), stride


def _vrm_reference(est: VrmEstimator, H, freqs, k, half_width, valid):
    """The estimator's definition, one triplet at a time, each λ by ``numpy.linalg.solve`` of the
    corrected [C-12] (tests/dsp/references.py), the weights ``|den|``, the viscous or hysteretic reading."""
    band = _vrm_band(est, H.size, k, half_width, valid)
    if band is None:
        return None
    m, stride = band
    pts = [k + stride * j for j in range(-m, m + 1)]
    c_max = math.tan(2.0 * math.atan(est.zeta_max)) if est.model == "viscous" else 2.0 * est.zeta_max
    lam_sum, w_sum, used = 0j, 0.0, 0
    for a, b, c in combinations(range(2 * m + 1), 3):
        if c - a < max(m, 2):
            continue
        pa, pb, pc = pts[a], pts[b], pts[c]
        f2 = [float(freqs[p]) ** 2 for p in (pa, pb, pc)]
        dba, dca = H[pb] - H[pa], H[pc] - H[pa]
        den = dba * (f2[2] - f2[0]) - dca * (f2[1] - f2[0])
        if abs(den) == 0.0:
            continue
        lam = c12_corrected(H[pa], H[pb], H[pc], *(float(freqs[p]) for p in (pa, pb, pc)))[0]
        if not lam.real > 0.0 or not lam.imag > 0.0 or lam.imag > c_max * lam.real:
            continue
        lam_sum += abs(den) * lam
        w_sum += abs(den)
        used += 1
    if used == 0:
        return None
    lam = lam_sum / w_sum
    if est.model == "viscous":
        fn, zeta = math.sqrt(abs(lam)), math.tan(0.5 * math.atan2(lam.imag, lam.real))
    else:
        fn, zeta = math.sqrt(lam.real), 0.5 * lam.imag / lam.real
    df = float(freqs[1] - freqs[0])
    if not (float(freqs[pts[0]]) - 2 * df <= fn <= float(freqs[pts[-1]]) + 2 * df and 0.0 < zeta <= est.zeta_max):
        return None
    return fn, zeta, used


@pytest.mark.parametrize("model", ["viscous", "hysteretic"])
@pytest.mark.parametrize("m_max", [2, 5, 10])
def test_vrm_equals_its_triplet_by_triplet_definition(model: Literal["viscous", "hysteretic"], m_max: int) -> None:
    rng = np.random.default_rng(m_max)
    wn1, wn2 = 2 * np.pi * 3.6, 2 * np.pi * 9.0
    w = 2 * np.pi * FREQS
    H = 4e3 / (wn1**2 - w**2 + 2j * 0.09 * wn1 * w) + 1e3 / (wn2**2 - w**2 + 2j * 0.05 * wn2 * w)
    H = H * (1 + 0.05 * (rng.standard_normal(H.size) + 1j * rng.standard_normal(H.size)))
    valid = np.ones(H.size, dtype=bool)
    valid[[30, 101, 102]] = False
    est = VrmEstimator(m_max=m_max, model=model)
    ks = [36, 92, 0, 3, 37, 100, 1020, 500]
    hws = [3.2, 2.3, 2.0, 5.0, 0.4, 1.0, 8.0, 30.0]  # different m and strides, edges, masked bins
    for mask in (None, valid):
        got = [est.estimate(H, FREQS, k, hw, mask) for k, hw in zip(ks, hws)]
        ref = [_vrm_reference(est, H, FREQS, k, hw, mask) for k, hw in zip(ks, hws)]
        assert [g is None for g in got] == [r is None for r in ref]
        assert sum(g is not None for g in got) >= 4
        for g, r in zip(got, ref):
            if g is not None:
                assert g[2] == r[2]
                assert g[0] == pytest.approx(r[0], rel=1e-12) and g[1] == pytest.approx(r[1], rel=1e-9)


def test_vrm_degenerate_spectra_give_none_without_warnings() -> None:
    est = VrmEstimator()
    with np.errstate(all="raise"):
        assert est.estimate(np.zeros(FREQS.size, dtype=complex), FREQS, 40, 3.0) is None
        assert est.estimate(np.ones(FREQS.size, dtype=complex), FREQS, 40, 3.0) is None


# ------------------------------------------------------------- whole step
def _savgol(x: np.ndarray, w: int, order: int) -> np.ndarray:
    """scipy's Savitzky–Golay filter of a complex spectrum (its edges fitted, mode='interp')."""
    return scipy.signal.savgol_filter(x.real, w, order, mode="interp") + 1j * scipy.signal.savgol_filter(x.imag, w, order, mode="interp")


def _scipy_peaks(v: np.ndarray, ratio: float, want: int) -> list[tuple[int, float]]:
    """The best ``want`` maxima of ``v`` (highest first) at least ``ratio`` above their prominence
    base (scipy.signal.find_peaks and peak_prominences), with their prominence in dB."""
    idx = scipy.signal.find_peaks(v)[0]
    prom = scipy.signal.peak_prominences(v, idx)[0]
    keep = [(int(p), float(v[p]), float(v[p] - q)) for p, q in zip(idx, prom) if v[p] >= (v[p] - q) * ratio]
    keep.sort(key=lambda t: -t[1])
    return [(p, 20.0 * math.log10(h / base)) for p, h, base in keep[:want]]


def _step_reference(idf: Identifier) -> list[tuple]:
    """The step's poles rebuilt from scipy and the solve, FWHM and VRM definitions."""
    from dsp_service.modal import log_weights

    cfg = idf.cfg
    H, valid = mimo_solve(idf._avg.state, cfg.det_threshold, cfg.power_floor)
    htot = H.mean(axis=0)
    lo, hi, sl = idf._lo, idf._hi, idf._sl
    assert valid[sl].all()  # so is every smoothing window of the search range, which lies within sl
    hs = _savgol(htot, cfg.smoothing_window, cfg.smoothing_order)[lo:hi]
    f = idf.freqs
    weights = log_weights(f[lo:hi], max(cfg.search_min_hz, f[1]), cfg.log_weight_exponent)
    peaks = _scipy_peaks(np.abs(hs) * weights, 10.0 ** (cfg.min_peak_prominence_db / 20.0), cfg.max_peaks)
    hd, vd, fd = htot[sl], valid[sl], f[sl]
    magd = np.abs(hd)
    r = max(1, (cfg.smoothing_window // 2) // 2)
    out, ks, hws = [], [], []
    for index, prom in peaks:
        k = index + lo - sl.start
        a = max(k - r, 0)
        k = a + int(np.argmax(magd[a : k + r + 1]))
        d, lv = parabola_vertex(magd, k, 1, 0.5)  # the three-point vertex
        fp, mp = fd[k] + d * (fd[1] - fd[0]), math.exp(lv)
        band = half_power_crossings(magd, fd, k, mp)
        assert band is not None and vd.all()
        bw = band[1] - band[0]
        hb = 0.5 * bw / (fd[1] - fd[0])
        d, lv = parabola_vertex(magd, k, min(8, int(round(0.5 * hb))))
        out.append([fd[k] + d * (fd[1] - fd[0]), math.exp(lv), zeta_from_half_power_width(bw, fp), prom])
        ks.append(k)
        hws.append(hb)
    est = VrmEstimator(cfg.vrm_points_per_side, cfg.vrm_band_factor, model=cfg.vrm_model)
    for row, k, hb in zip(out, ks, hws):
        row.append(_vrm_reference(est, hd, fd, k, hb, None))
    return [tuple(r) for r in out]


@pytest.mark.parametrize("seed", [1, 3])
def test_step_equals_its_definition_from_the_public_building_blocks(seed: int) -> None:
    """Every pole of the step against :func:`_step_reference`: frequency and VRM frequency to
    1e-11, magnitude, FWHM and VRM damping and prominence to 1e-9 (the least-squares peak, the
    half-power crossing and the VRM weights amplify the rounding of the smoothed spectrum, which
    scipy computes as a convolution in another order)."""
    n = 1024
    _, u, y = dataset(40 * n, seed=seed)
    idf = Identifier(IdentifierConfig(fft_width=n))
    checked = with_vrm = 0
    for s in range(0, u.shape[1], n // 8):
        idf.push(u[:, s : s + n // 8], y[:, s : s + n // 8])
        result = idf.step()
        if s < 10 * n or s % (n // 2):
            continue
        ref = _step_reference(idf)
        assert len(result.poles) == len(ref) == 2
        for pole, (fp, mp, zf, prom, vrm) in zip(result.poles, ref):
            assert pole.frequency_hz == pytest.approx(fp, rel=1e-11)
            assert pole.magnitude == pytest.approx(mp, rel=1e-9)
            assert pole.damping_fwhm == pytest.approx(zf, rel=1e-9)
            assert pole.prominence_db == pytest.approx(prom, rel=1e-9, abs=1e-9)
            if vrm is None:
                assert pole.damping_vrm is None and pole.natural_frequency_vrm_hz is None
            else:
                assert pole.natural_frequency_vrm_hz == pytest.approx(vrm[0], rel=1e-11)
                assert pole.damping_vrm == pytest.approx(vrm[1], rel=1e-9)
                with_vrm += 1
        checked += 1
    assert checked >= 20 and with_vrm >= checked
