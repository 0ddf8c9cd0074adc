"""Where a discrete OATF stage puts its zeros: its notch, its zeros in ``z``, and ``|F|`` at a mode's pole (thesis §3.3).

A stage ``F(z) = a0 + a1 z^-n + a2 z^-2n`` ([3-34], ``controller.oatf``)
cancels a mode when one of its zeros sits on the mode's pole
``z = e^(s Ts)``, ``s = −ζ ω_n + j ω_d``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from controller.oatf import StageDesign, frequency_response, transfer_function


def notch(stage: StageDesign, near_hz: float, f_hi: float, n_grid: int) -> tuple[float, float]:
    """The local minimum of ``|F|`` on (0, f_hi) nearest ``near_hz``: (frequency in Hz, ``|F|`` there).

    Local minima are found on an ``n_grid``-point grid and refined by Brent's
    method (``scipy.optimize.minimize_scalar``, bounded).
    """
    grid = np.linspace(0.0, f_hi, n_grid)
    mag = np.abs(frequency_response(grid, [stage]))
    interior = np.flatnonzero((mag[1:-1] <= mag[:-2]) & (mag[1:-1] <= mag[2:])) + 1
    if interior.size == 0:
        interior = np.array([int(np.argmin(mag))])
    i = int(interior[np.argmin(np.abs(grid[interior] - near_hz))])
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    res = minimize_scalar(
        lambda f: float(abs(frequency_response([f], [stage])[0])),
        bounds=(a, b),
        method="bounded",
        options={"xatol": 1e-10},
    )
    return float(res.x), float(res.fun)


def abs_at_pole(stage: StageDesign, frequency_hz: float, zeta: float) -> float:
    """``|F(e^(s Ts))|`` at the mode's pole ``s = −ζ ω_n + j ω_n √(1 − ζ²)``: 0 when the zero cancels the mode."""
    wn = 2 * math.pi * frequency_hz
    s = complex(-zeta * wn, wn * math.sqrt(1 - zeta * zeta))
    return float(abs(transfer_function([np.exp(s * stage.sample_period_s)], [stage])[0]))


def zeros(stage: StageDesign) -> np.ndarray:
    """All zeros of ``a0 z^(2n) + a1 z^n + a2`` (``numpy.roots``)."""
    n = stage.delay_samples
    poly = np.zeros(2 * n + 1)
    poly[[0, n, 2 * n]] = stage.coefficients
    return np.roots(poly)


def zeros_hz(stage: StageDesign) -> list[dict[str, float]]:
    """The zeros in the upper half plane as frequency (Hz) and radius, by frequency."""
    out = []
    for r in zeros(stage):
        ang = math.atan2(r.imag, r.real)
        if ang >= -1e-12:
            out.append({"frequency_hz": ang / (2 * math.pi * stage.sample_period_s), "radius": abs(r)})
    return sorted(out, key=lambda d: d["frequency_hz"])
