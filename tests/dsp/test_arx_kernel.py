"""dsp_service/arx_kernel.py: the compiled Givens update, back-substitution and
a-priori errors against LAPACK/BLAS (scipy, numpy) to round-off, and against a
plain-Python transcription of the same operations bit for bit (so no compiler
reassociated or fused anything: the bits are the same on every host)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg

from dsp_service.arx_kernel import absorb_rows, back_substitute, equation_errors


def _absorb_python(r: list[list[float]], rows: list[list[float]]) -> None:
    m = len(r)
    for row in rows:
        for k in range(m):
            b = row[k]
            if b == 0.0:
                continue
            a = r[k][k]
            h = math.sqrt(a * a + b * b)
            c, s = a / h, b / h
            r[k][k] = h
            row[k] = 0.0
            for j in range(k + 1, m):
                rkj, rij = r[k][j], row[j]
                r[k][j] = c * rkj + s * rij
                row[j] = c * rij - s * rkj


def _triangular(rng: np.random.Generator, m: int) -> np.ndarray:
    return np.triu(rng.standard_normal((m, m))) + 3.0 * np.eye(m)


@pytest.mark.parametrize("m,k", [(3, 1), (9, 7), (43, 15)])
def test_absorb_rows_is_the_qr_of_the_stacked_rows(m: int, k: int) -> None:
    rng = np.random.default_rng(m * 100 + k)
    r0 = _triangular(rng, m)
    rows = rng.standard_normal((k, m))
    ref = np.linalg.qr(np.vstack([r0, rows]), mode="r")
    r = r0.copy()
    absorb_rows(r, rows)
    assert np.all(rows == 0.0)
    assert np.array_equal(r, np.triu(r)) and np.all(np.diag(r) >= 0)
    # LAPACK's R differs by the sign of each row
    np.testing.assert_allclose(r, np.sign(np.diag(ref))[:, None] * ref, rtol=1e-10, atol=1e-12)


def test_absorb_rows_is_its_plain_python_transcription_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    r0 = _triangular(rng, 13)
    rows = rng.standard_normal((20, 13))
    rows[3, :4] = 0.0  # leading zeros: those rotations are skipped in both
    r_py, rows_py = r0.tolist(), rows.tolist()
    _absorb_python(r_py, rows_py)
    r = r0.copy()
    absorb_rows(r, rows)
    assert r.tolist() == r_py


def test_back_substitution_and_equation_errors_match_lapack_and_blas() -> None:
    rng = np.random.default_rng(8)
    p = 42
    r = _triangular(rng, p + 1)
    theta = np.empty(p)
    back_substitute(r, theta)
    np.testing.assert_allclose(theta, scipy.linalg.solve_triangular(r[:p, :p], r[:p, p]), rtol=1e-12, atol=1e-14)
    rows = rng.standard_normal((30, p + 1))
    e = np.empty(30)
    equation_errors(rows, theta, e)
    np.testing.assert_allclose(e, rows[:, p] - rows[:, :p] @ theta, rtol=1e-12, atol=1e-12)
    expected = []
    for row in rows.tolist():  # left to right, one rounding per product and per sum
        s = row[0] * float(theta[0])
        for j in range(1, p):
            s = s + row[j] * float(theta[j])
        expected.append(row[p] - s)
    assert e.tolist() == expected
