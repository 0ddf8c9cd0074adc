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
identifier's step smooths only the spectrum it searches, and only over the
search range (:func:`.kernel._smooth`, on the rows :meth:`FrequencySmoother.rows`
lays out); the downloads smooth every bin with the same compiled filter
(:meth:`FrequencySmoother.smooth`): each output bin sums its window in order,
the same bits on every host. Smoothing biases damping estimates upward
(§2.4.1); see the identifier's ``estimate_on_smoothed``.
"""

from __future__ import annotations

import functools
from fractions import Fraction

import numpy as np
from numpy.typing import NDArray

from . import kernel


def savgol_dot_coeffs(window: int, order: int, pos: int) -> NDArray[np.float64]:
    """``scipy.signal.savgol_coeffs(window, order, pos=pos, use="dot")``, each coefficient the
    correctly rounded value of the exact one (:func:`_exact_dot_coeffs`, worked out once
    per process for each ``(window, order, pos)``: every smoother of a run, and of every
    run in the process, shares them); a fresh array each call."""
    return np.array(_exact_dot_coeffs(int(window), int(order), int(pos)), dtype=np.float64)


@functools.lru_cache(maxsize=256)
def _exact_dot_coeffs(window: int, order: int, pos: int) -> tuple[float, ...]:
    """The coefficients of :func:`savgol_dot_coeffs`, each the correctly rounded value of the exact one.

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
    return tuple(float(sum(zi * Fraction(xj) ** i for i, zi in enumerate(z))) for xj in x)


class FrequencySmoother:
    """Savitzky–Golay smoother over ``n_bins`` bins; ``window <= 1`` means off (identity)."""

    def __init__(self, n_bins: int, window: int = 17, order: int = 2) -> None:
        self.n_bins = int(n_bins)
        self.window = int(window)
        self.order = int(order)
        self.enabled = self.window > 1
        self._all_valid = np.ones(self.n_bins, dtype=bool)
        self._zeros = np.zeros(self.n_bins, dtype=np.complex128)
        self._full: tuple[NDArray[np.float64], NDArray[np.intp], int, int] | None = None
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
        self.edge_lo = np.stack([savgol_dot_coeffs(w, self.order, k) for k in range(h)]) if h else np.zeros((0, w))
        self.edge_hi = np.stack([savgol_dot_coeffs(w, self.order, k) for k in range(h + 1, w)]) if h else np.zeros((0, w))
        # first bin of the fitting window used for each output bin
        self._starts = np.clip(np.arange(self.n_bins) - h, 0, self.n_bins - w)

    def rows(self, lo: int, hi: int) -> tuple[NDArray[np.float64], NDArray[np.intp], int, int]:
        """``(coef, starts, ia, ib)`` of the compiled smoothing (:func:`.kernel._smooth`) over bins
        ``lo … hi−1``: its rows and window starts, and its interior ``ia … ib`` (rows of one sliding
        window, the centre row; ``0, 0``: none)."""
        k = self.n_bins
        if self.enabled:
            h = self.half
            rows = []
            for i in range(lo, hi):
                if i < h:
                    rows.append(self.edge_lo[i])
                elif i >= k - h:
                    rows.append(self.edge_hi[i - (k - h)])
                else:
                    rows.append(self.centre)
            coef = np.ascontiguousarray(np.stack(rows), dtype=np.float64)
            starts = np.ascontiguousarray(self._starts[lo:hi], dtype=np.intp)
        else:
            coef = np.ones((hi - lo, 1))
            starts = np.arange(lo, hi, dtype=np.intp)
        steps = np.flatnonzero(np.diff(starts) == 1)  # consecutive rows of a sliding window
        if not steps.size:
            return coef, starts, 0, 0
        ia, ib = int(steps[0]), int(steps[-1]) + 2
        # the kernel's interior passes need a sliding window of one row (the centre row)
        if not (np.array_equal(starts[ia:ib], starts[ia] + np.arange(ib - ia)) and (coef[ia:ib] == coef[ia]).all()):
            return coef, starts, 0, 0
        return coef, starts, ia, ib

    def _run(self, x: NDArray[np.complex128], valid: NDArray[np.bool_]) -> tuple[NDArray[np.complex128], NDArray[np.bool_]]:
        """The compiled smoothing of every bin of the complex spectrum ``x`` and its validity."""
        if self._full is None:
            self._full = self.rows(0, self.n_bins)
        coef, starts, ia, ib = self._full
        out = np.empty(self.n_bins, dtype=np.complex128)
        vs = np.empty(self.n_bins, dtype=np.bool_)
        src = np.ascontiguousarray(x, dtype=np.complex128)
        kernel._smooth(src, np.ascontiguousarray(valid, dtype=np.bool_), 0, self.n_bins, coef, starts, out, vs, ia, ib, bool(valid.all()))
        return out, vs

    def smooth(self, x: NDArray[np.complexfloating]) -> NDArray[np.complex128]:
        """Smooth every bin of the complex spectrum ``x`` (shape ``(K,)`` or ``(m, K)``); returns a new array."""
        rows = np.asarray(x, dtype=np.complex128)
        if not self.enabled:
            return rows.copy()
        if rows.ndim == 1:
            return self._run(rows, self._all_valid)[0]
        return np.stack([self._run(row, self._all_valid)[0] for row in rows])

    def valid(self, valid: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """Validity of every smoothed bin: all raw bins of its fitting window valid."""
        return self._run(self._zeros, valid)[1]
