"""The fused post-FFT kernel of one identification step (``IdentifierConfig.kernel = 'numba'``).

One compiled call does, after the four FFTs, what the numpy reference path
(:mod:`.spectra`, :mod:`.mimo`, :mod:`.smoothing`, :meth:`.Identifier._find_peaks`)
does in about fifty small numpy calls:

1. the exponential average of the seven raw spectra, ``S' += c·conj(U_i)·X_j``
   (all bins; the sums of ``P11``, ``P22`` for the power floor in the same pass);
2. the corrected 2×2 ``H_tot`` solve on the solved slice, with its mask and,
   for the collinear bins, the dominant-direction (rank-1) solve (:mod:`.mimo`);
3. the Savitzky–Golay smoothing of ``H_tot`` over the search range (one
   coefficient row per output bin, the interior and edge rows of
   :class:`.smoothing.FrequencySmoother`) and the smoothed-bin validity;
4. the peak search on the linear weighted magnitude: scipy's local maxima,
   prominence bases by scipy's walk, highest first (:func:`.modal.find_modal_peaks`).

The arithmetic is the reference's, operation for operation, so results agree
to rounding (sums are taken in another order: a few ulps); the tests compare
both paths to 1e-12. The refinement, FWHM and VRM of the (at most
``max_peaks``) poles stay on the numpy path. Compiled with ``cache=True``;
:func:`warm_up` compiles (or loads) it before the first batch.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

_TINY = float(np.finfo(np.float64).tiny)


@intrinsic
def _fma(typingctx, a, b, c):  # type: ignore[no-untyped-def]
    """``a·b + c`` rounded once (LLVM ``fma``)."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return builder.fma(*args)

    return sig, codegen


# numpy's complex loops (its SIMD kernels on this kind of CPU) multiply with fused
# multiply-adds and take |z| as l·sqrt(1 + (s/l)²): the same here, so that the
# compiled step rounds exactly as the reference does (the 2×2 determinant of a
# few averages cancels, so one ulp there would show as 1e-13 in a damping).
@njit(cache=True, inline="always")
def _cmul(a, b):  # type: ignore[no-untyped-def]
    return complex(_fma(a.real, b.real, -(a.imag * b.imag)), _fma(a.real, b.imag, a.imag * b.real))


@njit(cache=True, inline="always")
def _cabs(z):  # type: ignore[no-untyped-def]
    x = abs(z.real)
    y = abs(z.imag)
    big = x if x > y else y
    small = y if x > y else x
    if big == 0.0:
        return 0.0
    r = small / big
    return big * math.sqrt(_fma(r, r, 1.0))


@njit(cache=True)
def _accumulate(X, c, state):  # type: ignore[no-untyped-def]
    """``state[r] += (conj(X_i)·c)·X_j`` for the seven spectra; returns ``(Σ P11.real, Σ P22.real)``."""
    k = X.shape[1]
    s11 = 0.0
    s22 = 0.0
    for b in range(k):
        u1 = X[0, b].conjugate() * c
        u2 = X[1, b].conjugate() * c
        x0 = X[0, b]
        x1 = X[1, b]
        x2 = X[2, b]
        x3 = X[3, b]
        state[0, b] += _cmul(u1, x0)  # P11
        state[1, b] += _cmul(u1, x1)  # P12
        state[2, b] += _cmul(u1, x2)  # P1y1
        state[3, b] += _cmul(u1, x3)  # P1y2
        state[4, b] += _cmul(u2, x1)  # P22
        state[5, b] += _cmul(u2, x2)  # P2y1
        state[6, b] += _cmul(u2, x3)  # P2y2
        s11 += state[0, b].real
        s22 += state[4, b].real
    return s11, s22


@njit(cache=True)
def _solve_tot(state, s0, s1, floor, det_threshold, dominant, out, valid, mode):  # type: ignore[no-untyped-def]
    """``H_tot`` on bins ``s0 … s1−1`` into ``out`` (with ``valid``, ``mode``); returns the valid count."""
    count = 0
    for b in range(s0, s1):
        p11 = state[0, b].real
        p22 = state[4, b].real
        p12 = state[1, b]
        prod = p11 * p22
        a12 = _cabs(p12)
        det = prod - a12 * a12
        ok = det >= prod * det_threshold and p11 > floor and p22 > floor
        if ok:
            inv4 = 0.25 / det
            A = state[2, b] + state[3, b]
            B = state[5, b] + state[6, b]
            d0 = complex(state[4, b].real - p12.real, state[4, b].imag + p12.imag)  # P22 − P21
            d1 = state[0, b] - p12  # P11 − P12
            out[b] = (_cmul(A, d0) + _cmul(B, d1)) * inv4
            valid[b] = True
            mode[b] = 2
            count += 1
            continue
        out[b] = 0.0
        valid[b] = False
        mode[b] = 0
        if not dominant or not (p11 + p22 > floor):
            continue
        # rank-1 minimum-norm solve along the dominant eigenvector (mimo.MimoSolver._dominant)
        half = 0.5 * (p11 - p22)
        disc = math.sqrt(half * half + (p12.real * p12.real + p12.imag * p12.imag))
        sigma = 0.5 * (p11 + p22) + disc
        if p11 >= p22:
            v1 = complex(sigma - p22, 0.0)
            v2 = p12.conjugate()
        else:
            v1 = p12
            v2 = complex(sigma - p11, 0.0)
        av1 = _cabs(v1)
        av2 = _cabs(v2)
        norm = math.sqrt(av1 * av1 + av2 * av2)
        rn = 1.0 / norm
        v1 = v1 * rn
        v2 = v2 * rn
        rs = 1.0 / sigma
        c0 = (_cmul(v1.conjugate(), state[2, b]) + _cmul(v2.conjugate(), state[5, b])) * rs
        c1 = (_cmul(v1.conjugate(), state[3, b]) + _cmul(v2.conjugate(), state[6, b])) * rs
        out[b] = _cmul(0.25 * (v1 + v2), c0 + c1)
        valid[b] = True
        mode[b] = 1
        count += 1
    return count


@njit(cache=True)
def _smooth(src, valid, lo, hi, coef, starts, hs, vs):  # type: ignore[no-untyped-def]
    """Savitzky–Golay rows ``coef[i]`` over ``src[starts[i] …]`` into ``hs[i]``; ``vs[i]`` = window all valid."""
    w = coef.shape[1]
    n_valid = 0
    for i in range(hi - lo):
        s = starts[i]
        re = 0.0
        im = 0.0
        ok = True
        for j in range(w):
            x = src[s + j]
            cj = coef[i, j]
            re += cj * x.real
            im += cj * x.imag
            if not valid[s + j]:
                ok = False
        hs[i] = complex(re, im)
        vs[i] = ok
        if ok:
            n_valid += 1
    return n_valid


@njit(cache=True)
def _peaks(hs, vs, n_valid, w_lin, weighted, ratio, want, v, order_buf, found_idx, found_prom):  # type: ignore[no-untyped-def]
    """Best ``want`` peaks of ``max(|hs|, tiny)·w`` (``Identifier._find_peaks``); returns how many."""
    size = hs.size
    if size < 3 or n_valid == 0:
        return 0
    vmin = np.inf
    for i in range(size):
        a = _cabs(hs[i])
        if a < _TINY:
            a = _TINY
        if weighted:
            a *= w_lin[i]
        v[i] = a
        if vs[i] and a < vmin:
            vmin = a
    if n_valid < size:
        for i in range(size):
            if not vs[i]:
                v[i] = vmin
    # scipy.signal._peak_finding_utils._local_maxima_1d
    m = 0
    i = 1
    last = size - 1
    while i < last:
        if v[i - 1] < v[i]:
            ahead = i + 1
            while ahead < last and v[ahead] == v[i]:
                ahead += 1
            if v[ahead] < v[i]:
                order_buf[m] = (i + ahead - 1) // 2
                m += 1
                i = ahead
        i += 1
    nf = 0
    if m:
        idx = order_buf[:m].copy()
        height = np.empty(m)
        for q in range(m):
            height[q] = v[idx[q]]
        order = np.argsort(height, kind="mergesort")[::-1]  # highest first, ties: the later first
        for q in range(m):
            p = idx[order[q]]
            hp = v[p]
            lmin = hp
            j = p
            while j >= 0 and v[j] <= hp:
                if v[j] < lmin:
                    lmin = v[j]
                j -= 1
            rmin = hp
            j = p
            while j < size and v[j] <= hp:
                if v[j] < rmin:
                    rmin = v[j]
                j += 1
            base = lmin if lmin > rmin else rmin
            if hp >= base * ratio:
                found_idx[nf] = p
                found_prom[nf] = 20.0 * math.log10(hp / base)
                nf += 1
                if nf == want:
                    break
    if nf:
        return nf
    g = 0
    for i in range(1, size):
        if v[i] > v[g]:
            g = i
    if g == 0 or g == size - 1:
        return 0
    lmin = v[0]
    for i in range(g + 1):
        if v[i] < lmin:
            lmin = v[i]
    rmin = v[g]
    for i in range(g, size):
        if v[i] < rmin:
            rmin = v[i]
    base = lmin if lmin > rmin else rmin
    found_idx[0] = g
    found_prom[0] = 20.0 * math.log10(v[g] / base)
    return 1


@njit(cache=True)
def post_fft(  # type: ignore[no-untyped-def]
    X, c, state, n_bins, power_floor, s0, s1, det_threshold, dominant, src, valid, mode,
    lo, hi, coef, starts, hs, vs, w_lin, weighted, ratio, want, v, order_buf, found_idx, found_prom, stats,
):
    """Stages 1–4 (module doc) in one call. ``stats`` ← (valid count on the slice, valid smoothed
    bins, peaks found, floor)."""
    s11, s22 = _accumulate(X, c, state)
    mean_power = (s11 + s22) / (2 * n_bins)
    floor = power_floor * mean_power + _TINY
    n_sl_valid = _solve_tot(state, s0, s1, floor, det_threshold, dominant, src, valid, mode)
    n_valid = _smooth(src, valid, lo, hi, coef, starts, hs, vs)
    nf = _peaks(hs, vs, n_valid, w_lin, weighted, ratio, want, v, order_buf, found_idx, found_prom)
    stats[0] = n_sl_valid
    stats[1] = n_valid
    stats[2] = nf
    stats[3] = floor


def warm_up() -> None:
    """Compile (or load from the cache) :func:`post_fft` with the types a step uses."""
    k, n_range = 9, 5
    X = np.zeros((4, k), dtype=np.complex128)
    X[0] = 1.0
    X[1] = np.arange(k) * 1j
    state = np.zeros((7, k), dtype=np.complex128)
    post_fft(
        X, 1.0, state, k, 1e-12, 0, k, 1e-3, True,
        np.zeros(k, dtype=np.complex128), np.zeros(k, dtype=np.bool_), np.zeros(k, dtype=np.uint8),
        1, 1 + n_range, np.ones((n_range, 3)) / 3.0, np.arange(n_range, dtype=np.intp),
        np.zeros(n_range, dtype=np.complex128), np.zeros(n_range, dtype=np.bool_), np.ones(n_range), True,
        1.4, 2, np.zeros(n_range), np.zeros(n_range, dtype=np.intp), np.zeros(16, dtype=np.intp),
        np.zeros(16), np.zeros(4),
    )
