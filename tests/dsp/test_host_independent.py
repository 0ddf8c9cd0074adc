"""The DSP's constants and channel means are computed in one defined way, not by
LAPACK/BLAS (whose last bits follow the host's kernel): each against the library
result it replaced, to round-off, and against its own definition, bit for bit."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
import scipy.signal

from dsp_service.kernel import detrend_window_ring, row_mean
from dsp_service.modal import parabola_fit_rows
from dsp_service.smoothing import savgol_dot_coeffs


@pytest.mark.parametrize("window,order", [(3, 1), (9, 2), (17, 2), (17, 4), (31, 3)])
def test_savgol_coefficients_are_scipys_correctly_rounded(window: int, order: int) -> None:
    for pos in range(window):
        ours = savgol_dot_coeffs(window, order, pos)
        np.testing.assert_allclose(ours, scipy.signal.savgol_coeffs(window, order, pos=pos, use="dot"), rtol=1e-9, atol=1e-10)
    # a polynomial of the fit's degree is reproduced exactly (to round-off) at every position
    x = np.arange(window, dtype=np.float64)
    poly = 0.5 + 0.25 * x - 0.01 * x**order
    for pos in range(window):
        assert float(savgol_dot_coeffs(window, order, pos) @ poly) == pytest.approx(poly[pos], abs=1e-9)


def test_savgol_centre_coefficients_are_the_textbook_fractions() -> None:
    """Savitzky and Golay's table: window 5, quadratic, centre: (−3, 12, 17, 12, −3)/35."""
    expected = [float(Fraction(k, 35)) for k in (-3, 12, 17, 12, -3)]
    assert savgol_dot_coeffs(5, 2, 2).tolist() == expected


@pytest.mark.parametrize("r", range(1, 9))
def test_parabola_rows_are_the_pseudo_inverse(r: int) -> None:
    j = np.arange(-r, r + 1, dtype=np.float64)
    a = np.vstack([np.ones_like(j), j, j * j]).T
    np.testing.assert_allclose(parabola_fit_rows(r), np.linalg.pinv(a), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("n", [1, 7, 8, 13, 512, 2051])
def test_row_mean_is_its_definition(n: int) -> None:
    x = np.random.default_rng(n).normal(3.0, 2.0, size=n)
    lanes = [0.0] * 8
    n8 = n - n % 8
    for i, v in enumerate(x.tolist()):
        lanes[i % 8 if i < n8 else 0] += v
    expected = (((lanes[0] + lanes[1]) + (lanes[2] + lanes[3])) + ((lanes[4] + lanes[5]) + (lanes[6] + lanes[7]))) / n
    assert row_mean(x) == expected
    assert row_mean(x) == pytest.approx(float(np.mean(x)), rel=1e-14)


@pytest.mark.parametrize("n", [8, 13, 64, 512, 2051])
def test_the_ring_detrend_takes_row_means_to_the_bit(n: int) -> None:
    """detrend_window_ring's means are row_mean's, bit for bit, and its output scipy's
    detrend='constant' times the window (to 1e-12), at every head position tried."""
    rng = np.random.default_rng(n)
    buf = rng.normal(5.0, 3.0, size=(4, 2 * n))
    window = np.hanning(n)
    for head in sorted({0, 1, 7, n // 2, n - 1}):
        means, out = np.empty(4), np.empty((4, n))
        detrend_window_ring(buf, head, means, window, out)
        view = buf[:, head : head + n]
        assert means.tolist() == [row_mean(np.ascontiguousarray(row)) for row in view]
        ref = scipy.signal.detrend(view, type="constant", axis=-1) * window
        np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
