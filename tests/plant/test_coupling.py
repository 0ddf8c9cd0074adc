"""RALF is a true 2x2 plant: both valves move both links' deflections.

The model is driven here without CAN: a plain proportional joint controller
(the thesis's proportional gains) holds a configuration from the sampled
extensions while independent broadband noise is added to both valve
commands.  The four transfer functions are estimated from averaged auto-
and cross-spectra (scipy.signal.welch/csd, no project DSP code), solved
2x2 per bin, and compared with the ground truth.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal as ss

from plant_emulator.model import PlantConfig, RalfArm, frequency_response, modal_parameters
from plant_emulator.model import kinematics as kin

FS = 200.0
HOLD = (math.radians(85.0), math.radians(25.0))
KP = np.array([7.5, 6.25])  # V/rad


@pytest.fixture(scope="module")
def record() -> tuple[np.ndarray, np.ndarray]:
    arm = RalfArm(PlantConfig(seed=3, home_theta_rad=HOLD))
    rng = np.random.default_rng(7)
    n = int(200 * FS)
    u = np.empty((n, 2))
    y = np.empty((n, 2))
    ref = np.array(HOLD)
    saturated = 0
    for k in range(n):
        reading = arm.sample()
        saturated += int(reading.saturated.any())
        v = reading.values_in
        th = np.array([kin.CYLINDER1.angle(v[0]), kin.CYLINDER2.angle(v[1])])
        u[k] = KP * (ref - th) + 0.05 * rng.standard_normal(2)
        arm.set_valve_voltages(u[k])
        y[k] = v[2:]
        arm.advance(1.0 / FS)
    assert arm.hard_stop_count == 0 and saturated == 0
    assert np.allclose(arm.truth().theta_rad, HOLD, atol=0.01)
    return u, y


def _mimo(u: np.ndarray, y: np.ndarray, nper: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """H[f, i, j] from input i to output j (conjugates as in scipy's csd)."""
    f, p11 = ss.welch(u[:, 0], FS, nperseg=nper)
    _, p22 = ss.welch(u[:, 1], FS, nperseg=nper)
    _, p12 = ss.csd(u[:, 0], u[:, 1], FS, nperseg=nper)
    p21 = np.conj(p12)
    den = p11 * p22 - np.abs(p12) ** 2
    H = np.empty((f.size, 2, 2), dtype=complex)
    for j in range(2):
        _, p1y = ss.csd(u[:, 0], y[:, j], FS, nperseg=nper)
        _, p2y = ss.csd(u[:, 1], y[:, j], FS, nperseg=nper)
        H[:, 0, j] = (p1y * p22 - p12 * p2y) / den
        H[:, 1, j] = (p2y * p11 - p21 * p1y) / den
    return f, H


def _peak(f: np.ndarray, mag: np.ndarray, lo: float, hi: float) -> float:
    """Frequency of the largest local maximum in [lo, hi], parabolic on log |H|."""
    idx = np.flatnonzero((f >= lo) & (f <= hi))
    i = idx[np.argmax(mag[idx])]
    assert idx[0] < i < idx[-1], "no interior peak"
    a, b, c = np.log(mag[i - 1 : i + 2])
    return float(f[i] + 0.5 * (a - c) / (a - 2 * b + c) * (f[1] - f[0]))


def test_four_transfer_functions_peak_at_the_true_modes(record: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = record
    f, H = _mimo(u, y)
    f_true, _ = modal_parameters(*HOLD)
    mag = np.abs(H)
    band = (f > 1.0) & (f < 12.0)
    # all four paths carry the resonances
    peak_mag = mag[band].max(axis=0)
    assert np.all(peak_mag > 0.05 * peak_mag.max()), peak_mag
    for r in range(2):
        other = f_true[1 - r]
        at = [np.argmin(abs(f - f_true[r])), np.argmin(abs(f - other))]
        # the path in which this mode stands out most against the other one
        score = mag[at[0]] / mag[at[1]]
        i, j = np.unravel_index(np.argmax(score), (2, 2))
        fp = _peak(f, mag[:, i, j], 0.8 * f_true[r], 1.2 * f_true[r])
        assert fp == pytest.approx(f_true[r], rel=0.02), (r, i, j)
    # the estimate agrees with the linearised model's transfer functions, once
    # the sampling is accounted for: the command is held for a sample period
    # (half a period of delay, a sinc), the deflections pass the anti-alias filter
    fb = f[band]
    b, a = ss.butter(2, 2 * np.pi * PlantConfig().antialias_cutoff_hz, analog=True)
    aa = ss.freqs(b, a, 2 * np.pi * fb)[1]
    hold = np.exp(-1j * np.pi * fb / FS) * np.sinc(fb / FS)
    Ha = frequency_response(*HOLD, fb) * (aa * hold)[:, None, None]
    err = np.abs(H[band] - Ha) / np.abs(Ha).max(axis=0)
    assert np.median(err) < 0.02 and np.percentile(err, 90) < 0.05
    # the inputs were independent, yet the closed loop correlates them only weakly
    assert abs(np.corrcoef(u.T)[0, 1]) < 0.5
