"""The recursive ARX's square-root information arithmetic, compiled and host-independent.

:class:`dsp_service.arx.RecursiveArx` keeps the upper-triangular ``R`` of its
weighted, augmented data matrix ``[Φ | y]`` and updates it once per batch.
These kernels do that arithmetic in one defined order of IEEE operations, so
an identification is the same on every host:

* :func:`absorb_rows` brings rows into ``R`` by Givens rotations, one row at a
  time, columns left to right: ``R ← triangular factor of [R; rows]``, the
  QR update of the module docstring of :mod:`dsp_service.arx`. It uses ``R``'s
  triangular structure (a row costs ``O(p²)``), where a Householder QR of the
  stacked matrix (LAPACK's ``dgeqrf`` through ``numpy.linalg.qr``) redoes the
  whole of ``R`` and rounds as the host's BLAS kernel blocks it: the same
  records then gave first passages through a 2 % band seconds apart under
  two OpenBLAS kernels of one machine.
* :func:`back_substitute` solves ``R[:p, :p] θ = R[:p, p]``.
* :func:`equation_errors` computes the a-priori errors ``y − φᵀθ`` with the
  products added left to right (no BLAS ``dgemv``).

Each rotation is ``h = √(a² + b²)``, ``c = a/h``, ``s = b/h`` (the diagonal
stays non-negative); numba compiles without fast-math, so nothing is
reassociated or fused into a multiply-add (tests/dsp/test_arx_kernel.py
holds the compiled kernels to a plain-Python transcription, bit for bit).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def absorb_rows(r: np.ndarray, rows: np.ndarray) -> None:
    """``r`` (``m × m`` upper triangular, in place) ← the triangular factor of ``[r; rows]``.

    ``rows`` (``k × m``) is used as scratch: it is zero on return."""
    m = r.shape[0]
    for i in range(rows.shape[0]):
        for k in range(m):
            b = rows[i, k]
            if b == 0.0:
                continue
            a = r[k, k]
            h = math.sqrt(a * a + b * b)
            c = a / h
            s = b / h
            r[k, k] = h
            rows[i, k] = 0.0
            for j in range(k + 1, m):
                rkj = r[k, j]
                rij = rows[i, j]
                r[k, j] = c * rkj + s * rij
                rows[i, j] = c * rij - s * rkj


@njit(cache=True)
def back_substitute(r: np.ndarray, theta: np.ndarray) -> None:
    """``theta`` (length ``p``) ← the solution of ``r[:p, :p] θ = r[:p, p]`` (``r`` is ``(p + 1) × (p + 1)``)."""
    p = theta.shape[0]
    for i in range(p - 1, -1, -1):
        t = r[i, p]
        for j in range(i + 1, p):
            t = t - r[i, j] * theta[j]
        theta[i] = t / r[i, i]


@njit(cache=True)
def equation_errors(rows: np.ndarray, theta: np.ndarray, out: np.ndarray) -> None:
    """``out[t] = rows[t, p] − Σ_j rows[t, j] θ_j`` (``p = len(theta)``), the sum left to right."""
    p = theta.shape[0]
    for t in range(rows.shape[0]):
        s = rows[t, 0] * theta[0]
        for j in range(1, p):
            s = s + rows[t, j] * theta[j]
        out[t] = rows[t, p] - s


def warm_up() -> None:
    """Compile the kernels (or load them from numba's on-disk cache) before the first batch."""
    r = np.eye(3)
    rows = np.ones((1, 3))
    absorb_rows(r, rows)
    theta = np.zeros(2)
    back_substitute(r, theta)
    equation_errors(np.ones((1, 3)), theta, np.zeros(1))
