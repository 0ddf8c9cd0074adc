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
from tests.plant.support import interior_peak_hz, mimo_h1

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


def test_four_transfer_functions_peak_at_the_true_modes(record: tuple[np.ndarray, np.ndarray]) -> None:
    u, y = record
    f, H = mimo_h1(u, y)
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
        fp = interior_peak_hz(f, mag[:, i, j], 0.8 * f_true[r], 1.2 * f_true[r])
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
