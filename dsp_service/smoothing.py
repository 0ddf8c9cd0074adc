"""Frequency smoothing of transfer-function estimates (thesis §2.4.1, §5).

A fixed-width, fixed-order local polynomial regression across frequency
bins, precomputed once as a linear filter: a Savitzky–Golay filter
(``scipy.signal.savgol_coeffs``). Window ``w = 2h + 1`` bins (17 in the
thesis's example), order ``p``.

* Complex input: the real coefficients are applied to the real and
  imaginary parts separately (``scipy.signal.savgol_filter`` would drop the
  imaginary part with a ComplexWarning).
* Edges: the ``h`` bins at either end use the *off-centre* coefficients of
  the polynomial fitted to the first (last) ``w`` bins (``pos=k``), i.e.
  scipy's ``mode='interp'``; no padding, no bias toward zero.
* Validity: a smoothed bin is valid only if every raw bin in its window is
  valid (invalid raw bins are 0 and would pull the fit down).

Smoothing is linear, so ``smooth(mean(H_ij)) = mean(smooth(H_ij))``; the
identifier smooths only the spectrum it searches, and only over the search
range (:meth:`FrequencySmoother.smooth_range`), with a plan prepared once
(:meth:`FrequencySmoother.range_plan`): the interior is one real product of
a sliding-window view of the spectrum's (re, im) floats with the
coefficients, each edge one small matrix product. Smoothing biases damping
estimates upward (§2.4.1); see the identifier's ``estimate_on_smoothed``.
"""

from __future__ import annotations

from collections.abc import Callable
from fractions import Fraction
from typing import TypeVar, cast

import numpy as np
from numpy.lib.stride_tricks import as_strided
from numpy.typing import NDArray

#: The spectra smoothed: real (float64) or complex (complex128) bins; the result has the input's dtype.
#: (Bound by np.inexact, not constrained to the two, so a buffer whose dtype is chosen at run time passes too.)
_Bins = TypeVar("_Bins", bound=np.inexact)


def _windows(x: NDArray[np.generic], start: int, count: int, width: int) -> NDArray[np.float64]:
    """Read-only ``(rows, width)`` float view: row ``m`` holds ``x[start + m : start + m + width]``.

    Complex ``x`` is viewed as interleaved (re, im) floats with two rows per
    output bin (its real and imaginary parts), so a single real product with
    the coefficients smooths both parts; ``x`` must be contiguous.
    """
    if np.iscomplexobj(x):
        xf = x.view(np.float64)
        step = xf.strides[0]
        w = as_strided(xf[2 * start :], shape=(2 * count, width), strides=(step, 2 * step))
    else:
        step = x.strides[0]
        w = as_strided(x[start:], shape=(count, width), strides=(step, step))
    w.flags.writeable = False
    return w


def _as_float(a: NDArray[np.inexact]) -> NDArray[np.float64]:
    """``a`` as float rows: complex ``(m,)`` → ``(m, 2)`` (re, im); real unchanged."""
    if np.iscomplexobj(a):
        return a.view(np.float64).reshape(-1, 2)
    # not complex: the real float64 bins (iscomplexobj does not narrow the type)
    return cast(NDArray[np.float64], a)


def savgol_dot_coeffs(window: int, order: int, pos: int) -> NDArray[np.float64]:
    """``scipy.signal.savgol_coeffs(window, order, pos=pos, use="dot")``, each coefficient the
    correctly rounded value of the exact one.

    The least-squares polynomial of degree ``order`` through ``window`` points,
    evaluated at point ``pos``: ``c_j = Σ_i z_i (j − pos)^i`` with ``(AᵀA) z = e₀``,
    ``A_ji = (j − pos)^i``, solved in rational arithmetic. scipy solves it by
    LAPACK least squares, which rounds as the host's kernel does; the last
    bit of the smoothing coefficients reached the identified peaks."""
    x = [j - pos for j in range(window)]
    m = order + 1
    # normal equations (AᵀA) z = e₀, exact; Gauss-Jordan with rational pivots (AᵀA is positive definite)
    a = [[Fraction(sum(xj ** (r + c) for xj in x)) for c in range(m)] + [Fraction(int(r == 0))] for r in range(m)]
    for col in range(m):
        piv = a[col][col]
        a[col] = [v / piv for v in a[col]]
        for r in range(m):
            if r != col and a[r][col] != 0:
                f = a[r][col]
                a[r] = [v - f * w for v, w in zip(a[r], a[col], strict=True)]
    z = [a[r][m] for r in range(m)]
    return np.array([float(sum(zi * Fraction(xj) ** i for i, zi in enumerate(z))) for xj in x], dtype=np.float64)


class FrequencySmoother:
    """Savitzky–Golay smoother over ``n_bins`` bins; ``window <= 1`` means off (identity)."""

    def __init__(self, n_bins: int, window: int = 17, order: int = 2) -> None:
        self.n_bins = int(n_bins)
        self.window = int(window)
        self.order = int(order)
        self.enabled = self.window > 1
        if not self.enabled:
            self.half = 0
            return
        if self.window % 2 == 0:
            raise ValueError(f"smoothing window must be odd, got {self.window}")
        if not 0 <= self.order < self.window:
            raise ValueError(f"smoothing order must be in [0, window), got {self.order}")
        if self.window > self.n_bins:
            raise ValueError(f"smoothing window {self.window} exceeds {self.n_bins} bins")
        w, h = self.window, self.window // 2
        self.half = h
        # 'dot' coefficients: estimate at window position pos = Σ c[j] x[start + j]
        self.centre = savgol_dot_coeffs(w, self.order, h)
        self._all_valid = np.ones(self.n_bins, dtype=bool)
        self.edge_lo = np.stack([savgol_dot_coeffs(w, self.order, k) for k in range(h)]) if h else np.zeros((0, w))
        self.edge_hi = np.stack([savgol_dot_coeffs(w, self.order, k) for k in range(h + 1, w)]) if h else np.zeros((0, w))
        # first bin of the fitting window used for each output bin
        self._starts = np.clip(np.arange(self.n_bins) - h, 0, self.n_bins - w)

    # ------------------------------------------------------------------ values
    def range_plan(self, x: NDArray[_Bins], lo: int, hi: int) -> Callable[[], NDArray[_Bins]]:
        """A prepared :meth:`smooth_range` of the buffer ``x`` (contiguous, shape ``(K,)``) over ``lo … hi−1``.

        Calling the plan smooths the *current* contents of ``x`` into an
        output array owned by the plan (overwritten by the next call) and
        returns it. Everything that depends only on the configuration (the
        sliding-window views, the edge coefficients) is set up here once.
        """
        k = self.n_bins
        if x.shape != (k,):
            raise ValueError(f"expected shape ({k},), got {x.shape}")
        if not x.flags.c_contiguous:
            raise ValueError("range_plan needs a contiguous buffer")
        lo, hi = max(0, int(lo)), min(k, int(hi))
        out = np.empty(max(hi - lo, 0), dtype=np.result_type(x.dtype, np.float64))
        if hi <= lo:
            return lambda: out
        if not self.enabled:
            src = x[lo:hi]

            def copy() -> NDArray[_Bins]:
                np.copyto(out, src)
                return out

            return copy
        h, w = self.half, self.window
        einsum, matmul = np.einsum, np.matmul
        parts: list[Callable[[], object]] = []
        a, b = max(lo, h), min(hi, k - h)  # interior bins [a, b)
        if b > a:
            win, coef = _windows(x, a - h, b - a, w), self.centre
            res = _as_float(out[a - lo : b - lo]).reshape(-1)
            parts.append(lambda: einsum("ij,j->i", win, coef, out=res))
        if lo < h:  # low edge: polynomial through the first w bins
            e = min(h, hi)
            elo, xlo, olo = self.edge_lo[lo:e], _as_float(x[:w]), _as_float(out[0 : e - lo])
            parts.append(lambda: matmul(elo, xlo, out=olo))
        if hi > k - h:  # high edge: polynomial through the last w bins
            s = max(lo, k - h)
            ehi, xhi, ohi = self.edge_hi[s - (k - h) : hi - (k - h)], _as_float(x[k - w :]), _as_float(out[s - lo :])
            parts.append(lambda: matmul(ehi, xhi, out=ohi))
        if len(parts) == 1:
            only = parts[0]

            def run1() -> NDArray[_Bins]:
                only()
                return out

            return run1

        def run() -> NDArray[_Bins]:
            for part in parts:
                part()
            return out

        return run

    def smooth_range(self, x: NDArray[_Bins], lo: int, hi: int) -> NDArray[_Bins]:
        """Smoothed values of the 1-D spectrum ``x`` at bins ``lo … hi−1`` (a new array)."""
        k = self.n_bins
        if x.shape != (k,):
            raise ValueError(f"expected shape ({k},), got {x.shape}")
        return self.range_plan(np.ascontiguousarray(x), lo, hi)().copy()

    def smooth(self, x: NDArray[_Bins]) -> NDArray[_Bins]:
        """Smooth every bin of ``x`` (shape ``(K,)`` or ``(m, K)``); returns a new array."""
        if x.ndim == 1:
            return self.smooth_range(x, 0, self.n_bins)
        return np.stack([self.smooth_range(row, 0, self.n_bins) for row in x])

    # -------------------------------------------------------------------- mask
    def valid_range(self, valid: NDArray[np.bool_], lo: int, hi: int) -> NDArray[np.bool_]:
        """Validity of smoothed bins ``lo … hi−1``: all raw bins of each fitting window valid.

        ``valid`` is full-length; only the raw bins the range's windows use are read.
        """
        lo, hi = max(0, int(lo)), min(self.n_bins, int(hi))
        if not self.enabled:
            return valid[lo:hi].copy()
        if hi <= lo:
            return np.zeros(0, dtype=bool)
        starts = self._starts[lo:hi]
        a, b = int(starts[0]), int(starts[-1]) + self.window  # raw bins read
        if np.count_nonzero(valid[a:b]) == b - a:  # the usual case: nothing masked
            return self._all_valid[: hi - lo].copy()
        bad = np.zeros(b - a + 1, dtype=np.intp)
        np.cumsum(~valid[a:b], out=bad[1:])
        s = starts - a
        return bad[s + self.window] == bad[s]

    def valid(self, valid: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Validity of every smoothed bin."""
        return self.valid_range(valid, 0, self.n_bins)
