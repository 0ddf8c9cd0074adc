"""The compiled identification step.

:func:`detrend_window_ring` (before the FFTs) and one call of :func:`step_packed`
(after them) are the identifier's step (:class:`.identifier.Identifier`):

1. the exponential [2-9] (or linear) average of the seven raw spectra,
   ``S' += c·conj(U_i)·X_j`` over all bins, with the sums of ``P11``, ``P22``
   for the power floor;
2. the corrected 2×2 ``H_tot`` solve [2-21 … 2-24] on the solved slice, its mask and, for
   the collinear bins, the dominant-direction (rank-1) solve (:mod:`.mimo`);
3. the Savitzky–Golay smoothing (§2.4.1) of ``H_tot`` over the search range (the
   interior and edge rows of :class:`.smoothing.FrequencySmoother`) and the
   smoothed-bin validity;
4. the peak search on the linear weighted magnitude: scipy's local maxima,
   prominence bases by scipy's walk, highest first;
5. per peak: relocation, the three-point and least-squares refinement,
   FWHM (exact or [B.1]) and VRM ([C-12 … C-14], as modal.VrmEstimator).

The complex products, ``|z|`` and complex division round as numpy's do on
this kind of CPU (fused multiply-adds, ``l·sqrt(1 + (s/l)²)``, Smith's
division); sums run in the order written. Compiled with ``cache=True``; :func:`warm_up` (called when the
Identifier is built) compiles or loads everything with the types a step
passes, so no batch pays compilation.

Every stage is a plain numba loop, compiled without fast-math, so sums run
in the order written. The one exception is :func:`_fma`, compiled with
fast-math contraction only: its ``a·b + c`` becomes one fused multiply-add,
as numpy's complex loops round on this kind of CPU.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numba import njit
from numpy.typing import NDArray

# The arrays a step passes (warm_up builds each of them); numba types them itself when compiling,
# these annotations document them and let mypy check the bodies.
F64 = NDArray[np.float64]
C128 = NDArray[np.complex128]
Bool = NDArray[np.bool_]
U8 = NDArray[np.uint8]
Intp = NDArray[np.intp]

_TINY = float(np.finfo(np.float64).tiny)


@njit(cache=True, error_model="numpy", fastmath={"contract"})
def _fma(a: float, b: float, c: float) -> float:
    """``a·b + c`` rounded once: compiled with fast-math contraction only, so LLVM fuses the
    product and the sum into one multiply-add (nothing else is relaxed). Not inlined at
    numba's level, which would give it the caller's flags; its callers are compiled without
    contraction, so the ``c`` they pass is never fused itself."""
    return a * b + c


# numpy's complex loops (its SIMD kernels on this kind of CPU) multiply with fused
# multiply-adds and take |z| as l·sqrt(1 + (s/l)²): the same here, so that the
# compiled step rounds exactly as numpy's complex arithmetic does (the 2×2 determinant
# of a few averages cancels, so one ulp there would show as 1e-13 in a damping).
@njit(cache=True, inline="always", error_model="numpy")
def _cmul(a: complex, b: complex) -> complex:
    return complex(_fma(a.real, b.real, -(a.imag * b.imag)), _fma(a.real, b.imag, a.imag * b.real))


@njit(cache=True, inline="always", error_model="numpy")
def _cabs(z: complex) -> float:
    x = abs(z.real)
    y = abs(z.imag)
    big = x if x > y else y
    small = y if x > y else x
    if big == 0.0:
        return 0.0
    r = small / big
    return big * math.sqrt(_fma(r, r, 1.0))


@njit(cache=True, error_model="numpy")
def row_mean(src: F64) -> float:
    """The mean of a 1-D row in one defined order (the channel means of detrend='constant').

    Eight running sums, sample ``i`` into sum ``i mod 8`` in order (a tail past the last
    multiple of 8 into sum 0), combined as
    ``((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))``, then divided by ``n``.
    A BLAS product (``x @ ones / n``, what this replaced) rounds as the host's
    kernel blocks it, which made an identification differ between hosts; eight
    independent sums still vectorize, and their bits do not depend on how."""
    n = src.shape[0]
    s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = 0.0
    n8 = n - n % 8
    for i in range(0, n8, 8):
        s0 += src[i]
        s1 += src[i + 1]
        s2 += src[i + 2]
        s3 += src[i + 3]
        s4 += src[i + 4]
        s5 += src[i + 5]
        s6 += src[i + 6]
        s7 += src[i + 7]
    for i in range(n8, n):  # a tail (N not a multiple of 8) goes to the first sum, in order
        s0 += src[i]
    return (((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7))) / n


@njit(cache=True, error_model="numpy", nogil=True)
def detrend_window_ring(buf: F64, head: int, means: F64, window: F64, out: F64) -> None:
    """``means[r]`` = :func:`row_mean` of row ``r`` of the history's window ``buf[:, head : head + N]``
    and ``out = (x − means[:, None]) · window`` (detrend='constant', then the window, as
    scipy.signal.csd does), read from the C-contiguous ring buffer itself. Each row goes through 1-D views: on
    the 2-D indices the compiler did not vectorize the loop (2.5–3× slower at N = 512 … 8192);
    the same elementwise roundings either way."""
    rows, n = out.shape
    for r in range(rows):
        src = buf[r, head : head + n]
        m = row_mean(src)
        means[r] = m
        dst = out[r]
        for i in range(n):
            dst[i] = (src[i] - m) * window[i]


@njit(cache=True, error_model="numpy")
def _accumulate(X: F64, c: float, state: F64) -> tuple[float, float]:
    """``state[r] += (conj(X_i)·c)·X_j`` for the seven spectra (the exponential [2-9] or linear
    average of the raw spectra, unnormalised: :class:`.spectra.SpectralAverager`); returns
    ``(Σ P11.real, Σ P22.real)`` over all bins, summed bin by bin in order.

    On float views (``X`` ``(4, 2K)``, ``state`` ``(7, 2K)``: (re, im) pairs). The product
    rounds as :func:`_cmul` does (one fused multiply-add per part), then adds to the state."""
    k = X.shape[1] // 2
    for r in range(7):
        xi = X[0] if r < 4 else X[1]
        xj = X[r] if r < 4 else X[r - 3]
        st = state[r]
        for b in range(k):
            ur = xi[2 * b] * c
            ui = -xi[2 * b + 1] * c
            br = xj[2 * b]
            bi = xj[2 * b + 1]
            st[2 * b] += _fma(ur, br, -(ui * bi))
            st[2 * b + 1] += _fma(ur, bi, ui * br)
    s11 = 0.0
    s22 = 0.0
    p11 = state[0]
    p22 = state[4]
    for b in range(k):
        s11 += p11[2 * b]
        s22 += p22[2 * b]
    return s11, s22


@njit(cache=True, error_model="numpy", inline="always")
def _full_rank(p11: float, p22: float, p12: complex, floor: float, det_threshold: float) -> tuple[bool, float]:
    """``(ok, det)`` of one bin's 2×2 solve [2-21 … 2-24]: ``det = P11 P22 − |P12|²``; ok when both
    input powers exceed ``floor`` and ``det / (P11 P22) ≥ det_threshold`` (:mod:`.mimo`). Without
    branches (the callers' loops vectorize)."""
    prod = p11 * p22
    a12 = _cabs(p12)
    det = prod - a12 * a12
    return (det >= prod * det_threshold) & (p11 > floor) & (p22 > floor), det


@njit(cache=True, error_model="numpy", inline="always")
def _dominant_direction(p11: float, p22: float, p12: complex) -> tuple[complex, complex, float]:
    """``(v1, v2, 1/σ₁)``: the unit eigenvector of the dominant eigenvalue σ₁ of ``[[P11, P12], [P21,
    P22]]`` (the better-conditioned of its two forms) for the rank-1 minimum-norm solve of a
    collinear bin, ``h_j = v (vᴴ r_j) / σ₁`` (:mod:`.mimo`'s module doc)."""
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
    return v1 * rn, v2 * rn, 1.0 / sigma


@njit(cache=True, error_model="numpy")
def solve_full(state: C128, s0: int, s1: int, floor: float, det_threshold: float, dominant: bool, H: C128, valid: Bool, mode: U8) -> int:
    """All four transfer functions ``H`` (rows H11, H12, H21, H22) on bins ``s0 … s1−1`` from the
    averaged spectra ``state``, with ``valid`` and ``mode`` (:mod:`.mimo`); returns the valid count.

    ``H1j = (P1yj P22 − P12 P2yj) / det``, ``H2j = (P2yj P11 − P21 P1yj) / det`` [2-21 … 2-24]
    (corrected) where :func:`_full_rank`; with ``dominant`` the masked bins whose input power
    clears ``floor`` along the dominant input direction (:func:`_dominant_direction`); the rest 0.
    The same operations as :func:`_solve_tot`, which solves their mean ``H_tot`` in one sum."""
    count = 0
    for i in range(s0, s1):
        p11 = state[0, i].real
        p22 = state[4, i].real
        p12 = state[1, i]
        ok, det = _full_rank(p11, p22, p12, floor, det_threshold)
        if ok:
            inv = 1.0 / det
            p21 = p12.conjugate()
            for j in range(2):
                y1 = state[2 + j, i]  # P1yj
                y2 = state[5 + j, i]  # P2yj
                h1 = complex(y1.real * p22, y1.imag * p22) - _cmul(y2, p12)
                h2 = complex(y2.real * p11, y2.imag * p11) - _cmul(y1, p21)
                H[j, i] = complex(h1.real * inv, h1.imag * inv)
                H[2 + j, i] = complex(h2.real * inv, h2.imag * inv)
            valid[i] = True
            mode[i] = 2
            count += 1
        elif dominant and p11 + p22 > floor:
            v1, v2, rs = _dominant_direction(p11, p22, p12)
            for j in range(2):
                c = (_cmul(v1.conjugate(), state[2 + j, i]) + _cmul(v2.conjugate(), state[5 + j, i])) * rs
                H[j, i] = _cmul(v1, c)
                H[2 + j, i] = _cmul(v2, c)
            valid[i] = True
            mode[i] = 1
            count += 1
        else:
            for r in range(4):
                H[r, i] = 0j
            valid[i] = False
            mode[i] = 0
    return count


@njit(cache=True, error_model="numpy", inline="always")
def input_power_floor(state: C128, power_floor: float) -> float:
    """``power_floor`` × the mean input power (``P11``, ``P22``) over all bins, plus the smallest
    normal float: the floor both input powers of a solved bin exceed (:mod:`.mimo`). Summed bin by
    bin in order."""
    s11 = 0.0
    s22 = 0.0
    for b in range(state.shape[1]):
        s11 += state[0, b].real
        s22 += state[4, b].real
    return power_floor * ((s11 + s22) / (2 * state.shape[1])) + _TINY


@njit(cache=True, error_model="numpy")
def _solve_tot(state: C128, s0: int, s1: int, floor: float, det_threshold: float, dominant: bool, out: C128, valid: Bool, mode: U8) -> int:
    """``H_tot`` on bins ``s0 … s1−1`` into ``out`` (with ``valid``, ``mode``); returns the valid count.

    Two passes: the corrected 2×2 solve [2-21…2-24] on every bin without branches (selects
    only, so the compiler vectorizes it: about 5× faster than bin by bin with its branches),
    then the dominant-direction solve of the bins it masked. The same operations per bin
    as :func:`solve_full` (its mask and dominant direction are theirs). Not inlined into :func:`step_packed`
    as the other stages are: inlined, its first pass no longer vectorized (0.66 → 2.4 µs at
    N = 2048)."""
    m = s1 - s0
    r0 = state[0, s0:s1]  # P11
    r1 = state[1, s0:s1]  # P12
    r2 = state[2, s0:s1]  # P1y1
    r3 = state[3, s0:s1]  # P1y2
    r4 = state[4, s0:s1]  # P22
    r5 = state[5, s0:s1]  # P2y1
    r6 = state[6, s0:s1]  # P2y2
    o = out[s0:s1]
    vd = valid[s0:s1]
    md = mode[s0:s1]
    count = 0
    for i in range(m):
        p11 = r0[i].real
        p22 = r4[i].real
        p12 = r1[i]
        ok, det = _full_rank(p11, p22, p12, floor, det_threshold)
        inv4 = 0.25 / det
        A = r2[i] + r3[i]
        B = r5[i] + r6[i]
        d0 = complex(r4[i].real - p12.real, r4[i].imag + p12.imag)  # P22 − P21
        d1 = r0[i] - p12  # P11 − P12
        h = (_cmul(A, d0) + _cmul(B, d1)) * inv4
        o[i] = h if ok else 0j
        vd[i] = ok
        md[i] = 2 if ok else 0
        count += 1 if ok else 0
    if not dominant:
        return count
    for i in range(m):
        if vd[i]:
            continue
        p11 = r0[i].real
        p22 = r4[i].real
        if not (p11 + p22 > floor):
            continue
        v1, v2, rs = _dominant_direction(p11, p22, r1[i])
        c0 = (_cmul(v1.conjugate(), r2[i]) + _cmul(v2.conjugate(), r5[i])) * rs
        c1 = (_cmul(v1.conjugate(), r3[i]) + _cmul(v2.conjugate(), r6[i])) * rs
        o[i] = _cmul(0.25 * (v1 + v2), c0 + c1)
        vd[i] = True
        md[i] = 1
        count += 1
    return count


@njit(cache=True, error_model="numpy", inline="always")
def _smooth_rows(src: C128, coef: F64, starts: Intp, hs: C128, i0: int, i1: int) -> None:
    """Rows ``i0 … i1−1`` of :func:`_smooth` one by one (each its own coefficients)."""
    w = coef.shape[1]
    for i in range(i0, i1):
        st = starts[i]
        a = 0.0
        b = 0.0
        for j in range(w):
            a += coef[i, j] * src[st + j].real
            b += coef[i, j] * src[st + j].imag
        hs[i] = complex(a, b)


@njit(cache=True, error_model="numpy", inline="always")
def _smooth(src: C128, valid: Bool, lo: int, hi: int, coef: F64, starts: Intp, hs: C128, vs: Bool, ia: int, ib: int, all_valid: bool) -> int:
    """Savitzky–Golay rows ``coef[i]`` over ``src[starts[i] …]`` into ``hs[i]`` (§2.4.1); ``vs[i]`` =
    window all valid.

    Each output bin sums its window in order ``j = 0 … w−1`` from 0.0. The rows ``ia … ib−1``
    (the interior: ``starts[i] = starts[ia] + i − ia`` and every row equal to ``coef[ia]``, the
    centre row; the Identifier sets ``ia``, ``ib`` so) are one filter over the (re, im) floats,
    applied tap by tap (each pass adds one tap's products to every output: the same sums in
    the same order, and a loop the compiler vectorizes), the edge rows one by one.
    ``all_valid``: every bin of the solved slice is valid, so every window is (it lies within
    the slice), and the validity count is skipped."""
    w = coef.shape[1]
    m = hi - lo
    if ib > ia:
        s0 = 2 * starts[ia]
        cnt = 2 * (ib - ia)
        sf = src.view(np.float64)
        out = hs.view(np.float64)[2 * ia : 2 * ib]
        taps = coef[ia]
        for t in range(cnt):
            out[t] = 0.0
        for j in range(w):
            cj = taps[j]
            x = sf[s0 + 2 * j : s0 + 2 * j + cnt]
            for t in range(cnt):
                out[t] += cj * x[t]
    if ib > ia:  # the edge rows around the interior
        _smooth_rows(src, coef, starts, hs, 0, ia)
        _smooth_rows(src, coef, starts, hs, ib, m)
    else:
        _smooth_rows(src, coef, starts, hs, 0, m)
    if all_valid:
        for i in range(m):
            vs[i] = True
        return m
    a = starts[0]
    b = starts[m - 1] + w
    bad = np.zeros(b - a + 1, dtype=np.intp)  # invalid raw bins before each position
    for q in range(a, b):
        bad[q - a + 1] = bad[q - a] + (0 if valid[q] else 1)
    n_valid = 0
    for i in range(m):
        s = starts[i] - a
        ok = bad[s + w] == bad[s]
        vs[i] = ok
        if ok:
            n_valid += 1
    return n_valid


_BLOCK = 16  #: bins per block of the peak search's walks
_SELECT_MAX = 16  #: up to this many local maxima the peak search picks the highest one by one


@njit(cache=True, error_model="numpy")
def _blocks_into(v: F64, bmin: F64, bmax: F64) -> None:
    """Minimum and maximum of each block of ``_BLOCK`` bins of ``v`` (the last one shorter) into
    ``bmin``, ``bmax`` (at least ``ceil(v.size / _BLOCK)`` long); a block holding a NaN gets a NaN
    maximum, so that a walk goes through it bin by bin."""
    size = v.size
    nb = (size + _BLOCK - 1) // _BLOCK
    for q in range(nb):
        a0 = q * _BLOCK
        a1 = min(a0 + _BLOCK, size)
        mn = v[a0]
        mx = v[a0]
        for i in range(a0 + 1, a1):
            x = v[i]
            mn = x if x < mn else mn
            mx = x if (x > mx or x != x) else mx
        bmin[q] = mn
        bmax[q] = mx


@njit(cache=True, error_model="numpy")
def _walk_min(v: F64, bmin: F64, bmax: F64, p: int, hp: float, step: int) -> float:
    """Minimum of ``v`` from ``p`` towards ``step`` (−1 left, +1 right) while ``v <= hp``: scipy's
    prominence walk, whole blocks (``bmin``, ``bmax`` of ``_BLOCK`` bins) at a time where the
    block's maximum is no higher than ``hp``."""
    size = v.size
    low = hp
    j = p
    while 0 <= j < size:
        q = j // _BLOCK
        r = j - q * _BLOCK
        if (r == (_BLOCK - 1 if step < 0 else 0)) and (step < 0 or j + _BLOCK <= size) and bmax[q] <= hp:
            mn = bmin[q]
            if mn < low:
                low = mn
            j += step * _BLOCK
            continue
        x = v[j]
        if not x <= hp:
            break
        if x < low:
            low = x
        j += step
    return low


@njit(cache=True, error_model="numpy", inline="always")
def _weighted_magnitude(hs: C128, vs: Bool, n_valid: int, w_lin: F64, weighted: bool, v: F64) -> None:
    """``v`` ← ``max(|hs|, tiny)·w`` (``w`` = 1 unless ``weighted``), invalid bins set to the smallest
    valid value. The magnitudes in a loop of their own (no branches: it vectorizes, 4-8x faster than
    with the smallest valid value tracked in it), that minimum only where bins are invalid."""
    size = hs.size
    if weighted:
        for i in range(size):
            a = _cabs(hs[i])
            v[i] = (_TINY if a < _TINY else a) * w_lin[i]
    else:
        for i in range(size):
            a = _cabs(hs[i])
            v[i] = _TINY if a < _TINY else a
    if n_valid < size:
        vmin = np.inf
        for i in range(size):
            if vs[i] and v[i] < vmin:
                vmin = v[i]
        for i in range(size):
            if not vs[i]:
                v[i] = vmin


@njit(cache=True, error_model="numpy", inline="always")
def _local_maxima(v: F64, out: Intp) -> int:
    """The local maxima of ``v`` into ``out`` (the middle of a plateau); returns how many
    (``scipy.signal._peak_finding_utils._local_maxima_1d``)."""
    m = 0
    i = 1
    last = v.size - 1
    while i < last:
        if v[i - 1] < v[i]:
            ahead = i + 1
            while ahead < last and v[ahead] == v[i]:
                ahead += 1
            if v[ahead] < v[i]:
                out[m] = (i + ahead - 1) // 2
                m += 1
                i = ahead
        i += 1
    return m


@njit(cache=True, error_model="numpy", inline="always")
def _prominent_maxima(v: F64, m: int, order_buf: Intp, ratio: float, want: int, found_idx: Intp, found_prom: F64, scratch: F64) -> int:
    """Of the ``m`` local maxima ``order_buf[:m]`` of ``v``, tried highest first (ties: the later first),
    the first ``want`` whose prominence (scipy's bases, the higher of the two walks' minima) is at
    least ``ratio``, into ``found_idx``, ``found_prom`` (dB); returns how many. With at most
    ``_SELECT_MAX`` maxima the highest untried one is picked at a time (``order_buf[m : 2m]`` marks
    them), with more in the order of a stable sort of their heights."""
    size = v.size
    nb = (size + _BLOCK - 1) // _BLOCK
    bmin = scratch[:nb]
    bmax = scratch[nb : 2 * nb]
    _blocks_into(v, bmin, bmax)
    idx = order_buf[:m]
    if m <= _SELECT_MAX:
        tried = order_buf[m : 2 * m]  # m ≤ (size − 1) / 2: within order_buf
        for q in range(m):
            tried[q] = 0
    else:
        height = np.empty(m)
        for q in range(m):
            height[q] = v[idx[q]]
        order = np.argsort(height, kind="mergesort")[::-1]  # highest first, ties: the later first
    nf = 0
    for q in range(m):
        if m <= _SELECT_MAX:
            best = -1
            hb = 0.0
            for t in range(m):  # the highest untried maximum; of equal ones the later (>=)
                if tried[t] == 0 and (best < 0 or v[idx[t]] >= hb):
                    best = t
                    hb = v[idx[t]]
            tried[best] = 1
            p = idx[best]
        else:
            p = idx[order[q]]
        hp = v[p]
        lmin = _walk_min(v, bmin, bmax, p, hp, -1)
        rmin = _walk_min(v, bmin, bmax, p, hp, 1)
        base = lmin if lmin > rmin else rmin
        if hp >= base * ratio:
            found_idx[nf] = p
            found_prom[nf] = 20.0 * math.log10(hp / base)
            nf += 1
            if nf == want:
                break
    return nf


@njit(cache=True, error_model="numpy", inline="always")
def _global_peak(v: F64, found_idx: Intp, found_prom: F64) -> int:
    """The global maximum of ``v`` as the one peak (its prominence over the whole range) when no
    local maximum is prominent enough; 0 when it lies on an edge."""
    size = v.size
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


@njit(cache=True, error_model="numpy", inline="always")
def _peaks(
    hs: C128,
    vs: Bool,
    n_valid: int,
    w_lin: F64,
    weighted: bool,
    ratio: float,
    want: int,
    v: F64,
    order_buf: Intp,
    found_idx: Intp,
    found_prom: F64,
    scratch: F64,
) -> int:
    """Best ``want`` peaks of ``max(|hs|, tiny)·w`` (``scipy.signal.find_peaks`` with its prominence, on the
    weighted magnitude); returns how many.

    The local maxima are tried highest first (ties: the later first), each against its
    prominence (:func:`_prominent_maxima`; ``order_buf`` holds the maxima and their marks,
    ``scratch`` the walks' block extremes, at least ``2·ceil(hs.size / _BLOCK)`` floats); with
    none prominent enough, the global maximum (:func:`_global_peak`)."""
    if hs.size < 3 or n_valid == 0:
        return 0
    _weighted_magnitude(hs, vs, n_valid, w_lin, weighted, v)
    m = _local_maxima(v, order_buf)
    nf = _prominent_maxima(v, m, order_buf, ratio, want, found_idx, found_prom, scratch) if m else 0
    if nf:
        return nf
    return _global_peak(v, found_idx, found_prom)


# Packed arguments of :func:`step_packed`: everything the stages take but the snapshot, its
# weight and the arrays other objects own (the averages, the solver's H_tot, mask and mode) and
# the smoothed spectrum, in three flat arrays: ``fk`` (float constants: the scalars ``FP_*``,
# then the smoothing rows, weights, frequency grids, refinement pseudo-inverses), ``ik`` (intp:
# the scalars ``IP_*``, the shapes and offsets of the packed arrays, the smoothing starts, the
# VRM triplets, scratch and the peaks found) and ``fw`` (float work: the weighted magnitude,
# the prominences, counters, |H|, the poles). A call then unboxes 11 arrays instead of 27
# (about 40 ns each; a 27-argument call with no work measured 1.05 µs, an 11-argument one 0.45).
FP_POWER_FLOOR, FP_DET, FP_RATIO, FP_BAND, FP_ZETA_MAX, FP_C_MAX, N_FP = range(7)
(
    IP_BINS,
    IP_S0,
    IP_S1,
    IP_DOMINANT,
    IP_LO,
    IP_HI,
    IP_IA,
    IP_IB,
    IP_WEIGHTED,
    IP_WANT,
    IP_FIRST,
    IP_ON_SMOOTHED,
    IP_RELOCATE,
    IP_FWHM_EXACT,
    IP_R_MAX,
    IP_M_MAX,
    IP_VISCOUS,
    N_IP,
) = range(18)
# shapes and offsets of the packed arrays, in ``ik`` after the scalars
(
    IK_W,
    IK_N_SL,
    IK_TRI_M,
    IK_TRI_Q,
    IK_N_MAG,
    IK_COEF,
    IK_W_LIN,
    IK_F_SL,
    IK_F_RANGE,
    IK_PINV,
    IK_STARTS,
    IK_TRI,
    IK_N_TRI,
    IK_ORDER,
    IK_IDX,
    IK_V,
    IK_PROM,
    IK_STATS,
    IK_MAG,
    IK_OUT,
    IK_END,
) = range(N_IP, N_IP + 21)


def pack_arguments(
    fp: F64,
    ip: Intp,
    coef: F64,
    w_lin: F64,
    f_sl: F64,
    f_range: F64,
    pinv: F64,
    starts: Intp,
    tri: Intp,
    n_tri: Intp,
    n_mag: int,
) -> tuple[F64, Intp, F64, dict[str, Any]]:
    """``(fk, ik, fw, views)`` for :func:`step_packed`: the scalars ``fp`` (``FP_*``) and ``ip``
    (``IP_*``) and the constant arrays copied in, scratch and outputs allocated; ``views`` names
    every packed array as a view into them (``coef`` … ``n_tri``, and ``order``, ``idx``, ``v``,
    ``prom``, ``stats``, ``mag``, ``out``: what a step writes, and ``tail``: ``prom``, ``stats`` and
    ``out`` as one flat view, in this order)."""
    m = coef.shape[0]
    want = int(ip[IP_WANT])
    f_parts = [("coef", coef), ("w_lin", w_lin), ("f_sl", f_sl), ("f_range", f_range), ("pinv", pinv)]
    i_parts = [("starts", starts), ("tri", tri), ("n_tri", n_tri), ("order", np.zeros(m, dtype=np.intp)), ("idx", np.zeros(want, dtype=np.intp))]
    # prom, stats and out last and in this order: the Identifier reads them with one tolist ("tail")
    w_parts = [("v", np.zeros(m)), ("mag", np.zeros(n_mag)), ("prom", np.zeros(want)), ("stats", np.zeros(4)), ("out", np.zeros((want, 6)))]
    slots = {"coef": IK_COEF, "w_lin": IK_W_LIN, "f_sl": IK_F_SL, "f_range": IK_F_RANGE, "pinv": IK_PINV}
    slots.update({"starts": IK_STARTS, "tri": IK_TRI, "n_tri": IK_N_TRI, "order": IK_ORDER, "idx": IK_IDX})
    slots.update({"v": IK_V, "prom": IK_PROM, "stats": IK_STATS, "mag": IK_MAG, "out": IK_OUT})
    ik_head = np.zeros(IK_END, dtype=np.intp)
    ik_head[:N_IP] = ip
    ik_head[IK_W], ik_head[IK_N_SL], ik_head[IK_N_MAG] = coef.shape[1], f_sl.size, n_mag
    ik_head[IK_TRI_M], ik_head[IK_TRI_Q] = tri.shape[0], tri.shape[1]

    def lay(parts: list[tuple[str, Any]], start: int) -> int:
        at = start
        for name, arr in parts:
            ik_head[slots[name]] = at
            at += arr.size
        return at

    fk = np.empty(lay(f_parts, N_FP))
    ik = np.empty(lay(i_parts, IK_END), dtype=np.intp)
    fw = np.empty(lay(w_parts, 0))
    fk[:N_FP] = fp
    ik[:IK_END] = ik_head
    views: dict[str, Any] = {}
    for flat, parts in ((fk, f_parts), (ik, i_parts), (fw, w_parts)):
        for name, arr in parts:
            at = int(ik_head[slots[name]])
            view = flat[at : at + arr.size].reshape(arr.shape)
            view[...] = arr
            views[name] = view
    views["tail"] = fw[int(ik_head[IK_PROM]) :]
    return fk, ik, fw, views


@njit(cache=True, error_model="numpy", inline="always")
def _average_and_solve(X: F64, c: float, fk: F64, ik: Intp, state: C128, src: C128, valid: Bool, mode: U8) -> tuple[int, float]:
    """Stages 1 and 2 of :func:`step_packed` (from stage ``IP_FIRST``): ``(valid count on the slice,
    power floor)``; from stage 3 the count of the caller's solve and a floor of 0."""
    s0 = ik[IP_S0]
    s1 = ik[IP_S1]
    first = ik[IP_FIRST]
    if first > 2:  # solved by the caller
        n_sl_valid = 0
        for i in range(s0, s1):
            if valid[i]:
                n_sl_valid += 1
        return n_sl_valid, 0.0
    # 1. the seven spectra into the averages, and the power floor (input_power_floor's, with the
    # sums the averaging makes on its way)
    if first == 1:
        s11, s22 = _accumulate(X, c, state.view(np.float64))
        floor = fk[FP_POWER_FLOOR] * ((s11 + s22) / (2 * ik[IP_BINS])) + _TINY
    else:
        floor = input_power_floor(state, fk[FP_POWER_FLOOR])
    # 2. H_tot on the slice
    return _solve_tot(state, s0, s1, floor, fk[FP_DET], ik[IP_DOMINANT] != 0, src, valid, mode), floor


@njit(cache=True, error_model="numpy", inline="always")
def _stage_poles(fk: F64, ik: Intp, fw: F64, src: C128, valid: Bool, hs: C128, vs: Bool, nf: int, n_valid: int, n_sl_valid: int) -> None:
    """Stage 5 of :func:`step_packed`: the refinement, FWHM and VRM of the ``nf`` peaks found, on the
    smoothed spectrum (``IP_ON_SMOOTHED``) or the solved slice, into the packed pole rows."""
    m = ik[IP_HI] - ik[IP_LO]
    want = ik[IP_WANT]
    r_max = ik[IP_R_MAX]
    tm = ik[IK_TRI_M]
    tq = ik[IK_TRI_Q]
    s0 = ik[IP_S0]
    s1 = ik[IP_S1]
    idx = ik[ik[IK_IDX] : ik[IK_IDX] + want]
    mag = fw[ik[IK_MAG] : ik[IK_MAG] + ik[IK_N_MAG]]
    o = ik[IK_PINV]
    pinv = fk[o : o + (r_max + 1) * 3 * (2 * r_max + 1)].reshape((r_max + 1, 3, 2 * r_max + 1))
    o = ik[IK_TRI]
    tri = ik[o : o + tm * tq * 3].reshape((tm, tq, 3))
    n_tri = ik[ik[IK_N_TRI] : ik[IK_N_TRI] + tm]
    o = ik[IK_OUT]
    out = fw[o : o + want * 6].reshape((want, 6))
    relocate, exact, m_max, viscous = ik[IP_RELOCATE], ik[IP_FWHM_EXACT] != 0, ik[IP_M_MAX], ik[IP_VISCOUS] != 0
    band, zeta_max, c_max = fk[FP_BAND], fk[FP_ZETA_MAX], fk[FP_C_MAX]
    if ik[IP_ON_SMOOTHED] != 0:
        f_range = fk[ik[IK_F_RANGE] : ik[IK_F_RANGE] + m]
        all_smoothed = n_valid == m
        poles(hs, vs, all_smoothed, f_range, 0, idx, nf, relocate, exact, pinv, r_max, m_max, band, zeta_max, c_max, viscous, tri, n_tri, mag[:m], out)
    else:
        f_sl = fk[ik[IK_F_SL] : ik[IK_F_SL] + ik[IK_N_SL]]
        all_sl = n_sl_valid == s1 - s0
        offset = ik[IP_LO] - s0
        sl_src, sl_valid = src[s0:s1], valid[s0:s1]
        poles(
            sl_src,
            sl_valid,
            all_sl,
            f_sl,
            offset,
            idx,
            nf,
            relocate,
            exact,
            pinv,
            r_max,
            m_max,
            band,
            zeta_max,
            c_max,
            viscous,
            tri,
            n_tri,
            mag[: s1 - s0],
            out,
        )


@njit(cache=True, error_model="numpy", nogil=True)
def step_packed(X: F64, c: float, fk: F64, ik: Intp, fw: F64, state: C128, src: C128, valid: Bool, mode: U8, hs: C128, vs: Bool) -> None:
    """The identification step after the FFTs (module doc, stages 1–5) on the packed arguments
    of :func:`pack_arguments` (views into ``fk``, ``ik``, ``fw``), from stage ``IP_FIRST``:

    1. the snapshot ``X`` (float view, ``(4, 2K)``) averaged with weight ``c`` into ``state``;
    2. ``H_tot`` solved on the slice into ``src`` (``valid``, ``mode``) with the power floor of
       ``state``;
    3. ``src`` (``valid``: solved by the caller from stage 3) smoothed over the search range into
       ``hs`` (``vs``), the peaks searched and their poles estimated on the smoothed
       (``IP_ON_SMOOTHED``) or the solved spectrum.

    ``stats`` ← (valid count on the slice, valid smoothed bins, peaks found, power floor (0 from
    stage 3)). The stages are inlined here (``inline="always"``): through functions of 32 and
    48 arguments not inlined, every array argument was passed as its seven fields and
    reference-counted, about 0.9 µs a step. Releases the GIL: the boards of several rigs in
    one process step on several cores."""
    m = ik[IP_HI] - ik[IP_LO]
    w = ik[IK_W]
    want = ik[IP_WANT]
    s0 = ik[IP_S0]
    s1 = ik[IP_S1]
    o = ik[IK_COEF]
    coef = fk[o : o + m * w].reshape((m, w))
    starts = ik[ik[IK_STARTS] : ik[IK_STARTS] + m]
    stats = fw[ik[IK_STATS] : ik[IK_STATS] + 4]
    # 1., 2. the averages and H_tot on the slice (or the caller's solve)
    n_sl_valid, floor = _average_and_solve(X, c, fk, ik, state, src, valid, mode)
    # 3. smoothing: every bin of the slice valid (the usual case), so is every window, which lies within it
    all_valid = n_sl_valid == s1 - s0 and starts[0] >= s0 and starts[m - 1] + w <= s1
    n_valid = _smooth(src, valid, ik[IP_LO], ik[IP_HI], coef, starts, hs, vs, ik[IP_IA], ik[IP_IB], all_valid)
    # 4. peaks (the poles' |H| buffer, free until stage 5, as scratch)
    v = fw[ik[IK_V] : ik[IK_V] + m]
    order = ik[ik[IK_ORDER] : ik[IK_ORDER] + m]
    w_lin = fk[ik[IK_W_LIN] : ik[IK_W_LIN] + m]
    idx = ik[ik[IK_IDX] : ik[IK_IDX] + want]
    prom = fw[ik[IK_PROM] : ik[IK_PROM] + want]
    mag = fw[ik[IK_MAG] : ik[IK_MAG] + ik[IK_N_MAG]]
    nf = _peaks(hs, vs, n_valid, w_lin, ik[IP_WEIGHTED] != 0, fk[FP_RATIO], want, v, order, idx, prom, mag)
    stats[0] = n_sl_valid
    stats[1] = n_valid
    stats[2] = nf
    stats[3] = floor
    if nf:
        # 5. refinement, FWHM and VRM of the peaks
        _stage_poles(fk, ik, fw, src, valid, hs, vs, nf, n_valid, n_sl_valid)


def compiled_entry(dispatcher: Any, args: tuple[Any, ...]) -> Callable[..., Any]:
    """The compiled overload of ``dispatcher`` for exactly these argument types, to be called
    without the dispatcher's per-call type resolution (about 60 ns per argument).

    Compiles (or loads from the cache) by calling once with ``args``: the caller
    must pass the same arrays (or arrays of the very same types) every time.
    Returns the dispatcher itself if numba's internals are not as expected."""
    dispatcher(*args)
    try:
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        return dispatcher.overloads[sig].entry_point
    except (AttributeError, KeyError):  # another numba: the dispatcher works too, just slower
        return dispatcher


def warm_up() -> None:
    """Compile (or load from numba's cache) :func:`detrend_window_ring`, :func:`_accumulate` and
    :func:`step_packed` (and what they call) with the types the identifier passes, the Welch
    segments' :func:`row_mean` and the downloads' :func:`solve_full`, :func:`input_power_floor` and
    :func:`_smooth`."""
    k, n_range = 40, 20
    rng = np.random.default_rng(0)
    ring = rng.standard_normal((4, 2 * (2 * k - 2)))
    detrend_window_ring(ring, 3, np.zeros(4), np.ones(2 * k - 2), np.empty((4, 2 * k - 2)))
    history = ring[:, 3 : 3 + 2 * k - 2]
    history.flags.writeable = False
    row_mean(history[0])  # the Welch segments' means (spectra.SegmentedSpectralEstimator), on the history's read-only view
    X = rng.standard_normal((4, k)) + 1j * rng.standard_normal((4, k))
    state = np.zeros((7, k), dtype=np.complex128)
    _accumulate(X.view(np.float64), 1.0, state.view(np.float64))  # alone: the settings whose solve runs before the search
    # the downloads (mimo.MimoSolver, smoothing.FrequencySmoother), called from Python
    H = np.zeros((4, k), dtype=np.complex128)
    valid = np.zeros(k, dtype=np.bool_)
    floor = input_power_floor(state, 1e-12)
    solve_full(state, 0, k, floor, 1e-3, True, H, valid, np.zeros(k, dtype=np.uint8))
    _smooth(H[0], valid, 0, k, np.ones((k, 1)), np.arange(k, dtype=np.intp), np.empty(k, dtype=np.complex128), np.empty(k, dtype=np.bool_), 0, 0, False)
    tri = np.zeros((2, 1, 3), dtype=np.intp)
    tri[1, 0] = (-1, 0, 1)
    fp = np.array([1e-12, 1e-3, 1.0, 1.5, 0.5, 1.0])
    ip = np.array([k, 0, k, 1, 10, 10 + n_range, 0, n_range, 1, 2, 1, 0, 1, 1, 1, 1, 1], dtype=np.intp)  # IP_FIRST 1
    for smoothed in (0, 1):
        ip[IP_ON_SMOOTHED] = smoothed
        fk, ik, fw, _ = pack_arguments(
            fp,
            ip,
            np.ones((n_range, 3)) / 3.0,
            np.ones(n_range),
            np.arange(k, dtype=np.float64),
            np.arange(10.0, 10.0 + n_range),
            np.zeros((2, 3, 3)),
            np.arange(9, 9 + n_range, dtype=np.intp),
            tri,
            np.array([0, 1], dtype=np.intp),
            k,
        )
        step_packed(
            X.view(np.float64),
            1.0,
            fk,
            ik,
            fw,
            state,
            np.zeros(k, dtype=np.complex128),
            np.zeros(k, dtype=np.bool_),
            np.zeros(k, dtype=np.uint8),
            np.zeros(n_range, dtype=np.complex128),
            np.zeros(n_range, dtype=np.bool_),
        )


# ---------------------------------------------------------------------------
# Stage 5: refinement, FWHM and VRM of the peaks (as modal.py defines them)
# ---------------------------------------------------------------------------
_SQRT_HALF = math.sqrt(0.5)
_ZETA_MAX_HALF_POWER = math.sqrt((2.0 - math.sqrt(2.0)) / 4.0)
_SQRT2 = math.sqrt(2.0)


@njit(cache=True, inline="always", error_model="numpy")
def _cdiv(a: complex, b: complex) -> complex:
    """numpy's complex division (Smith's algorithm)."""
    br = b.real
    bi = b.imag
    if abs(br) >= abs(bi):
        rat = bi / br
        scl = 1.0 / (br + bi * rat)
        return complex((a.real + a.imag * rat) * scl, (a.imag - a.real * rat) * scl)
    rat = br / bi
    scl = 1.0 / (bi + br * rat)
    return complex((a.real * rat + a.imag) * scl, (a.imag * rat - a.real) * scl)


@njit(cache=True, error_model="numpy")
def _refine_peak(mag: F64, k: int) -> tuple[float, float]:
    if 0 < k < mag.size - 1:
        a = math.log(max(mag[k - 1], _TINY))
        b = math.log(max(mag[k], _TINY))
        c = math.log(max(mag[k + 1], _TINY))
        curv = a - 2.0 * b + c
        if curv < 0.0:
            d = min(0.5, max(-0.5, 0.5 * (a - c) / curv))
            return d, b - 0.25 * (a - c) * d
        return 0.0, b
    return 0.0, math.log(max(mag[k], _TINY))


@njit(cache=True, error_model="numpy")
def _refine_ls(mag: F64, k: int, r: int, pinv: F64, r_max: int) -> tuple[float, float]:
    r = max(1, min(r, r_max, k, mag.size - 1 - k))
    w = 2 * r + 1
    c0 = 0.0
    c1 = 0.0
    c2 = 0.0
    for j in range(w):
        yj = math.log(max(mag[k - r + j], _TINY))
        c0 += pinv[r, 0, j] * yj
        c1 += pinv[r, 1, j] * yj
        c2 += pinv[r, 2, j] * yj
    if not c2 < 0.0:
        return 0.0, math.log(max(mag[k], _TINY))
    d = min(float(r), max(-float(r), -0.5 * c1 / c2))
    return d, c0 + c1 * d + c2 * d * d


@njit(cache=True, error_model="numpy")
def _half_power(mag: F64, f0: float, df: float, k: int, peak_mag: float, vd: Bool, check: bool, max_bins: int) -> tuple[bool, float, float]:
    """``(ok, f_left, f_right)``: the half-power crossings nearest bin ``k`` on the grid ``f0 + i·df``
    (:func:`.modal.half_power_bandwidth`), at most ``max_bins`` bins each side, interpolated linearly
    in power; not ok where a side does not drop below half power in reach or (``check``) a
    straddling bin is invalid."""
    thr = peak_mag * _SQRT_HALF
    size = mag.size
    if k < 1 or k >= size - 1:
        return False, 0.0, 0.0
    lo = max(0, k - max_bins)
    hi = min(size, k + max_bins + 1)
    i0 = -1
    for i in range(k - 1, lo - 1, -1):
        if mag[i] < thr:
            i0 = i
            break
    j1 = -1
    for i in range(k + 1, hi):
        if mag[i] < thr:
            j1 = i
            break
    if i0 < 0 or j1 < 0:
        return False, 0.0, 0.0
    if check and not (vd[i0] and vd[i0 + 1] and vd[j1 - 1] and vd[j1]):
        return False, 0.0, 0.0
    half = thr * thr
    pa = mag[i0] * mag[i0]
    pb = mag[i0 + 1] * mag[i0 + 1]
    t = (half - pa) / (pb - pa) if pb != pa else 0.5
    fl = f0 + (i0 + t) * df
    i1 = j1 - 1
    pa = mag[i1] * mag[i1]
    pb = mag[i1 + 1] * mag[i1 + 1]
    t = (half - pa) / (pb - pa) if pb != pa else 0.5
    return True, fl, f0 + (i1 + t) * df


@njit(cache=True, error_model="numpy")
def _zeta_fwhm(bw: float, fp: float, exact: bool) -> float:
    if not exact:
        return bw / (2.0 * fp)
    rho = bw / fp
    if not rho > 0.0:
        return 0.0
    if rho >= _SQRT2:
        return _ZETA_MAX_HALF_POWER
    c = 1.0 - 0.5 * rho * rho
    return math.sqrt(max(0.0, 0.5 * (1.0 - 1.0 / math.sqrt(2.0 - c * c))))


@njit(cache=True, error_model="numpy")
def _vrm_lambdas(g: F64) -> None:
    """``g[9]``, ``g[10]``, ``g[11]`` ← Re λ, Im λ and the weight ``|den|`` of each VRM triplet
    (Appendix C, :func:`.modal.vrm_lambdas`) from its squared frequencies ``g[0:3]`` and H
    values ``g[3:9]`` (re, im at a, b, c). Contiguous rows and no branches, so the compiler
    vectorizes the loop, divisions included; a zero ``den`` gives inf or NaN, which
    :func:`_vrm` skips by its zero weight, as the one-loop form did before dividing."""
    f2a = g[0]
    f2b = g[1]
    f2c = g[2]
    ar = g[3]
    ai = g[4]
    br = g[5]
    bi = g[6]
    cr = g[7]
    ci = g[8]
    lre = g[9]
    lim = g[10]
    wt = g[11]
    for q in range(lre.size):
        cab = f2c[q] - f2a[q]
        bab = f2b[q] - f2a[q]
        dba = complex(br[q] - ar[q], bi[q] - ai[q])
        dca = complex(cr[q] - ar[q], ci[q] - ai[q])
        fb = f2b[q] * cab
        fc = f2c[q] * bab
        den = complex(dba.real * cab - dca.real * bab, dba.imag * cab - dca.imag * bab)
        num = complex(dba.real * fb - dca.real * fc, dba.imag * fb - dca.imag * fc)
        wt[q] = _cabs(den)
        lam = _cdiv(num, den)
        lre[q] = lam.real
        lim[q] = lam.imag


@njit(cache=True, error_model="numpy", inline="always")
def _vrm_plan(vd: Bool, check: bool, n: int, k: int, hw: float, m_max: int, band_factor: float) -> tuple[int, int]:
    """``(m, s)`` of one peak's VRM band (modal.VrmEstimator._plan): ``m`` points each side of bin ``k``
    with a stride of ``s`` bins within ``±band_factor·hw`` bins, the array and (``check``) the valid
    bins around the peak; ``m`` = 0: no band."""
    h = max(1, int(np.rint(band_factor * hw)))
    h = min(h, k, n - 1 - k)
    if h >= 1 and check:
        for i in range(k - h, k + h + 1):
            if not vd[i]:
                dist = abs(i - k) - 1
                if dist < h:
                    h = dist
    if h < 1:
        return 0, 0
    m = min(h, m_max)
    s = max(1, int(np.rint(h / m)))
    if m * s > h:
        m = h // s
    return m, s


@njit(cache=True, error_model="numpy", inline="always")
def _vrm_gather(hd: C128, fd: F64, k: int, s: int, tm: Intp, nq: int) -> F64:
    """The triplets' squared frequencies and H values as contiguous rows (``g[0:9]``, :func:`_vrm_lambdas`
    fills ``g[9:12]``) for the ``nq`` triplets ``tm`` of offsets around bin ``k`` in strides of ``s``."""
    g = np.empty((12, nq))
    for q in range(nq):
        a = k + s * tm[q, 0]
        b = k + s * tm[q, 1]
        c = k + s * tm[q, 2]
        g[0, q] = fd[a] * fd[a]
        g[1, q] = fd[b] * fd[b]
        g[2, q] = fd[c] * fd[c]
        g[3, q] = hd[a].real
        g[4, q] = hd[a].imag
        g[5, q] = hd[b].real
        g[6, q] = hd[b].imag
        g[7, q] = hd[c].real
        g[8, q] = hd[c].imag
    return g


@njit(cache=True, error_model="numpy", inline="always")
def _vrm_average(g: F64, nq: int, c_max: float) -> tuple[int, float, float, float]:
    """``(used, Σw·Re λ, Σw·Im λ, Σw)`` over the physical triplets of ``g`` (weights ``|den|``; a
    zero weight skipped), summed in order."""
    lre = g[9]
    lim = g[10]
    wt = g[11]
    bounded = 0.0 < c_max < np.inf
    wr = 0.0
    wi = 0.0
    ws = 0.0
    used = 0
    for q in range(nq):
        w = wt[q]
        if w == 0.0:
            continue
        re = lre[q]
        im = lim[q]
        if bounded:
            good = im <= re * c_max
        else:
            good = re > 0.0
        if not (good and im > 0.0):
            continue
        wr += w * re
        wi += w * im
        ws += w
        used += 1
    return used, wr, wi, ws


@njit(cache=True, error_model="numpy", inline="always")
def vrm_reading(re: float, im: float, viscous: bool) -> tuple[float, float]:
    """``(f_n, ζ)`` of the VRM eigenvalue ``λ = re + i·im`` (in squared frequency units): viscous
    ``f_n = √|λ|``, ``ζ = tan(arg λ / 2) = Im λ / (|λ| + Re λ)``; hysteretic [C-13, C-14]
    ``f_n = √Re λ``, ``ζ = η/2 = Im λ / (2 Re λ)``; ``(0, 0)`` for ``Re λ ≤ 0`` (not physical)."""
    if re <= 0.0:
        return 0.0, 0.0
    if viscous:
        mod = math.hypot(re, im)
        return math.sqrt(mod), im / (mod + re)
    return math.sqrt(re), 0.5 * im / re


@njit(cache=True, error_model="numpy")
def _vrm(
    hd: C128,
    fd: F64,
    vd: Bool,
    check: bool,
    k: int,
    hw: float,
    m_max: int,
    band_factor: float,
    zeta_max: float,
    c_max: float,
    viscous: bool,
    tri: Intp,
    n_tri: Intp,
) -> tuple[bool, float, float, int]:
    """``(ok, f_n, ζ, used)`` of one peak (modal.VrmEstimator._plan and ._solve).

    Three passes, the same arithmetic per triplet and the same sums in the same order as
    one loop: the triplets' squared frequencies and H values gathered into contiguous
    rows (:func:`_vrm_gather`), λ and the weight of every triplet (:func:`_vrm_lambdas`,
    vectorized; with the gathers in it the compiler left it scalar), then the good ones
    summed (:func:`_vrm_average`); the averaged λ read as a mode [C-13, C-14] or viscously."""
    m, s = _vrm_plan(vd, check, hd.size, k, hw, m_max, band_factor)
    if m < 1:
        return False, 0.0, 0.0, 0
    nq = n_tri[m]
    g = _vrm_gather(hd, fd, k, s, tri[m], nq)
    _vrm_lambdas(g)
    used, wr, wi, ws = _vrm_average(g, nq, c_max)
    if used == 0 or not ws > 0.0:
        return False, 0.0, 0.0, used
    fn, zeta = vrm_reading(wr / ws, wi / ws, viscous)
    df = fd[1] - fd[0]
    f_lo = fd[k - s * m] - 2.0 * df
    f_hi = fd[k + s * m] + 2.0 * df
    if f_lo <= fn <= f_hi and 0.0 < zeta <= zeta_max:
        return True, fn, zeta, used
    return False, 0.0, 0.0, used


@njit(cache=True, error_model="numpy", inline="always")
def poles(
    hd: C128,
    vd: Bool,
    all_valid: bool,
    fd: F64,
    offset: int,
    idx: Intp,
    nf: int,
    relocate: int,
    fwhm_exact: bool,
    pinv: F64,
    r_max: int,
    m_max: int,
    band_factor: float,
    zeta_max: float,
    c_max: float,
    viscous: bool,
    tri: Intp,
    n_tri: Intp,
    mag: F64,
    out: F64,
) -> None:
    """The poles of the peaks (the rational fits run after, in the Identifier): ``out[i]`` ← (f_peak, |H| peak, ζ_FWHM or NaN,
    ok, f_n VRM or NaN, ζ_VRM or NaN) of peak ``i``; ``mag`` ← |hd|."""
    size = hd.size
    for i in range(size):
        mag[i] = _cabs(hd[i])
    f0 = fd[0]
    df = fd[1] - f0
    check = not all_valid
    for p in range(nf):
        k = idx[p] + offset
        a = max(k - relocate, 0)
        b = min(k + relocate + 1, size)
        best = a
        for i in range(a + 1, b):
            if mag[i] > mag[best]:
                best = i
        k = best
        d, lv = _refine_peak(mag, k)
        fk = fd[k]
        f_peak = fk + d * df
        m_peak = math.exp(lv)
        zeta_fwhm = np.nan
        half_bins = 2.0
        ok = all_valid or vd[k]
        if ok:
            found, fl, fr = _half_power(mag, f0, df, k, m_peak, vd, check, 64)
            if found:
                bw = fr - fl
                zeta_fwhm = _zeta_fwhm(bw, f_peak, fwhm_exact)
                half_bins = 0.5 * bw / df
                d, lv = _refine_ls(mag, k, int(np.rint(0.5 * half_bins)), pinv, r_max)
                f_peak = fk + d * df
                m_peak = math.exp(lv)
        out[p, 0] = f_peak
        out[p, 1] = m_peak
        out[p, 2] = zeta_fwhm
        out[p, 3] = 1.0 if ok else 0.0
        out[p, 4] = np.nan
        out[p, 5] = np.nan
        if ok:
            good, fn, zeta, _ = _vrm(hd, fd, vd, check, k, half_bins, m_max, band_factor, zeta_max, c_max, viscous, tri, n_tri)
            if good:
                out[p, 4] = fn
                out[p, 5] = zeta
