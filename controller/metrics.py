"""The thesis's cost functions (§4.2.1): RMS deflection velocity and acceleration per link.

Deflection velocity is the slope of a linear least-squares fit over a sliding
window of 10 samples; deflection acceleration is the second derivative of a
quadratic fit over 40 samples.  A polynomial least-squares fit evaluated at a
fixed position in a fixed-width window is a linear function of the window's
samples, so both are precomputed FIR filters: Savitzky-Golay derivative
coefficients (``scipy.signal.savgol_coeffs(window, order, deriv, delta=Ts,
pos=...)``).  The cost is the standard deviation of each estimate over the
run, per link (the thesis's "RMS").

Causal or centred.  Both regressions differentiate as often as their order
(the slope of a line, the curvature of a parabola), so the derivative is the
same at every point of the window: the taps do not depend on where the fit
is evaluated, and the choice is only which time an estimate is attributed
to.  The default, ``alignment="centred"``, attributes it to the centre of the
window (no phase lag relative to the deflection; for an even window that is
half-way between two samples): right for recorded runs, for plots against
the deflection and for the RMS costs.  ``alignment="causal"`` attributes it
to the newest sample: what a running loop has at tick ``k`` is the centred
estimate delayed by ``(window - 1) / 2`` samples (22.5 ms for velocity,
97.5 ms for acceleration at 200 Hz).  :class:`DerivativeEstimate` carries the
exact time of each value.  Only full windows are used: a run of ``n`` samples
gives ``n - window + 1`` estimates, so the standard deviation is over those.

Both filters are low-pass (at 200 Hz): the 10-sample slope (45 ms span)
passes a 5 Hz mode's velocity at 0.94 of its amplitude (0.97 at 3.6 Hz),
the 40-sample quadratic (195 ms span) passes a 5 Hz mode's acceleration at
0.46 (0.68 at 3.6 Hz, 0.03 at 10 Hz), so the acceleration cost weights the
first mode and hides higher ones; see
:meth:`RegressionDerivative.gain`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from scipy.signal import savgol_coeffs

FloatArray = npt.NDArray[np.float64]
Alignment = Literal["centred", "causal"]

__all__ = [
    "Alignment",
    "CostReport",
    "DerivativeEstimate",
    "RegressionDerivative",
    "acceleration_filter",
    "deflection_acceleration",
    "deflection_velocity",
    "percent_of_baseline",
    "rms_costs",
    "velocity_filter",
]

VELOCITY_WINDOW = 10
"""Samples in the sliding linear regression for deflection velocity (§4.2.1)."""
ACCELERATION_WINDOW = 40
"""Samples in the sliding quadratic regression for deflection acceleration (§4.2.1)."""


@dataclass(frozen=True)
class RegressionDerivative:
    """A sliding polynomial-regression derivative as an FIR filter.

    ``taps`` are in convolution order: the estimate from the window
    ``x[k - window + 1 .. k]`` is ``sum_j taps[j] x[k - j]`` and refers to
    time ``t[k] - lag_samples Ts``.
    """

    window: int
    polyorder: int
    deriv: int
    sample_period_s: float
    alignment: Alignment
    taps: FloatArray

    @property
    def lag_samples(self) -> float:
        """How far (samples) the evaluation point lies behind the newest sample of the window."""
        return 0.0 if self.alignment == "causal" else (self.window - 1) / 2.0

    def gain(self, freqs_hz: npt.ArrayLike) -> FloatArray:
        """|estimate| / |true derivative| for a sinusoid at ``freqs_hz`` (1 at low frequency)."""
        f = np.asarray(freqs_hz, dtype=float)
        w = 2.0 * math.pi * f
        j = np.arange(self.window) - self.lag_samples
        resp = np.sum(self.taps * np.exp(-1j * w[..., None] * j * self.sample_period_s), axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(resp) / np.abs((1j * w) ** self.deriv)

    def apply(self, x: npt.ArrayLike, t0_s: float = 0.0) -> DerivativeEstimate:
        """Filter the samples ``x`` (1-D, or 2-D with samples along axis 0) over full windows only."""
        xa = np.asarray(x, dtype=float)
        n = xa.shape[0]
        if n < self.window:
            raise ValueError(f"need at least {self.window} samples, got {n}")
        m = n - self.window + 1
        out = np.zeros((m, *xa.shape[1:]))
        for j, c in enumerate(self.taps):
            out += c * xa[self.window - 1 - j : self.window - 1 - j + m]
        times = t0_s + (np.arange(m) + self.window - 1 - self.lag_samples) * self.sample_period_s
        return DerivativeEstimate(values=out, t_s=times)


@dataclass(frozen=True)
class DerivativeEstimate:
    """Derivative estimates and the time each one refers to."""

    values: FloatArray
    t_s: FloatArray


def _regression(window: int, polyorder: int, deriv: int, sample_period_s: float, alignment: Alignment) -> RegressionDerivative:
    if window <= polyorder:
        raise ValueError(f"window ({window}) must exceed polyorder ({polyorder})")
    if not sample_period_s > 0.0:
        raise ValueError("sample_period_s must be positive")
    if alignment == "centred":
        pos = None  # savgol_coeffs: window // 2 if odd, else the half-sample centre
    elif alignment == "causal":
        pos = window - 1
    else:
        raise ValueError(f"alignment must be 'centred' or 'causal', got {alignment!r}")
    taps = np.asarray(savgol_coeffs(window, polyorder, deriv=deriv, delta=sample_period_s, pos=pos), dtype=float)
    return RegressionDerivative(window, polyorder, deriv, float(sample_period_s), alignment, taps)


def velocity_filter(sample_period_s: float = 0.005, window: int = VELOCITY_WINDOW, alignment: Alignment = "centred") -> RegressionDerivative:
    """Slope of a sliding linear regression over ``window`` samples (§4.2.1)."""
    return _regression(window, 1, 1, sample_period_s, alignment)


def acceleration_filter(sample_period_s: float = 0.005, window: int = ACCELERATION_WINDOW, alignment: Alignment = "centred") -> RegressionDerivative:
    """Second derivative of a sliding quadratic regression over ``window`` samples (§4.2.1)."""
    return _regression(window, 2, 2, sample_period_s, alignment)


def deflection_velocity(
    x: npt.ArrayLike, sample_period_s: float = 0.005, *, window: int = VELOCITY_WINDOW, alignment: Alignment = "centred"
) -> DerivativeEstimate:
    """Deflection velocity (units of ``x`` per s) over full windows."""
    return velocity_filter(sample_period_s, window, alignment).apply(x)


def deflection_acceleration(
    x: npt.ArrayLike,
    sample_period_s: float = 0.005,
    *,
    window: int = ACCELERATION_WINDOW,
    alignment: Alignment = "centred",
) -> DerivativeEstimate:
    """Deflection acceleration (units of ``x`` per s^2) over full windows."""
    return acceleration_filter(sample_period_s, window, alignment).apply(x)


@dataclass(frozen=True)
class CostReport:
    """RMS (standard deviation over the run) of deflection velocity and acceleration, per link."""

    velocity_rms: FloatArray
    acceleration_rms: FloatArray

    def as_dict(self) -> dict[str, list[float]]:
        return {"velocity_rms": self.velocity_rms.tolist(), "acceleration_rms": self.acceleration_rms.tolist()}


def rms_costs(
    deflection: npt.ArrayLike,
    sample_period_s: float = 0.005,
    *,
    velocity_window: int = VELOCITY_WINDOW,
    acceleration_window: int = ACCELERATION_WINDOW,
    alignment: Alignment = "centred",
) -> CostReport:
    """The §4.2.1 costs of a run: ``deflection`` is ``(n_samples,)`` or ``(n_samples, n_links)``."""
    d = np.asarray(deflection, dtype=float)
    d2 = d[:, None] if d.ndim == 1 else d
    v = deflection_velocity(d2, sample_period_s, window=velocity_window, alignment=alignment).values
    a = deflection_acceleration(d2, sample_period_s, window=acceleration_window, alignment=alignment).values
    return CostReport(velocity_rms=np.std(v, axis=0), acceleration_rms=np.std(a, axis=0))


def percent_of_baseline(cost: CostReport, baseline: CostReport) -> CostReport:
    """Costs as a percentage of a baseline run's (§4.2.3 reports both)."""
    return CostReport(
        velocity_rms=100.0 * cost.velocity_rms / baseline.velocity_rms,
        acceleration_rms=100.0 * cost.acceleration_rms / baseline.acceleration_rms,
    )
