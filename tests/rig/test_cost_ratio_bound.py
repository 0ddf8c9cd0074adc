"""Why §4.3's group-1 acceleration cannot be met (docs/simulation-calibration.md): the §4.2.1 cost
estimators at 200 Hz bound the ratio acceleration RMS / velocity RMS of any signal whose power lies
below 27.4 Hz by max |H_acc(f)| / |H_vel(f)| = 16.3 rad/s (at 4.1 Hz; it exceeds that only above 27.4 Hz), where the thesis's group 1 needs 26.5.

Reference: the estimators are least-squares polynomial derivatives over 10 and 40 samples, i.e.
scipy's Savitzky–Golay derivative filters; their gains come from scipy.signal.freqz, and the
estimators of controller.metrics are measured on sinusoids against them.
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from controller.metrics import deflection_acceleration, deflection_velocity

FS = 200.0
THESIS_GROUP1_RATIO = 23.594 / 0.890


def _gain_ratio(f: np.ndarray) -> np.ndarray:
    cv = scipy.signal.savgol_coeffs(10, 1, deriv=1, delta=1 / FS, use="conv")
    ca = scipy.signal.savgol_coeffs(40, 2, deriv=2, delta=1 / FS, use="conv")
    hv = scipy.signal.freqz(cv, worN=f, fs=FS)[1]
    ha = scipy.signal.freqz(ca, worN=f, fs=FS)[1]
    return np.abs(ha) / np.abs(hv)


def test_the_cost_estimators_are_the_savitzky_golay_derivatives() -> None:
    t = np.arange(0.0, 20.0, 1 / FS)
    for f in (0.7, 2.5, 4.1, 5.0, 9.3, 17.0):
        x = np.sin(2 * np.pi * f * t + 0.3)
        measured = np.std(deflection_acceleration(x).values) / np.std(deflection_velocity(x).values)
        assert abs(measured / _gain_ratio(np.array([f]))[0] - 1.0) < 0.01, f


def test_the_acceleration_to_velocity_ratio_is_bounded_below_27_hz() -> None:
    f = np.arange(0.05, 27.4, 0.01)
    r = _gain_ratio(f)
    assert 16.0 < r.max() < 16.5 and abs(f[r.argmax()] - 4.13) < 0.05
    # the thesis's group-1 ratio is out of reach for any signal with its power below 27.4 Hz
    assert r.max() < 0.65 * THESIS_GROUP1_RATIO
    # it is reached only close to the 10-sample slope's first zero (28.6 Hz), where no trajectory-driven ring has power
    f_hi = np.arange(27.0, 29.0, 0.01)
    assert 27.9 < f_hi[_gain_ratio(f_hi) >= THESIS_GROUP1_RATIO].min() < 28.6


def test_the_thesis_rig_ratios_fit_the_estimators_at_200_hz_and_only_group_1_does_not() -> None:
    # Table 4-1 row (a): acceleration / velocity per link of the rig's unfiltered runs, 13.1-15.2 rad/s,
    # the range these estimators give a 3.6-4.4 Hz ring (15.9-16.3) with some slower deflection mixed in
    battery = {
        (5.0, True): (0.317, 0.359, 4.807, 5.354),
        (5.0, False): (0.262, 0.273, 3.833, 3.573),
        (4.0, True): (0.426, 0.478, 6.413, 7.109),
        (4.0, False): (0.358, 0.353, 5.177, 4.613),
    }
    ratios = [row[2 + i] / row[i] for row in battery.values() for i in (0, 1)]
    bound = _gain_ratio(np.arange(0.05, 27.4, 0.01)).max()
    assert all(13.0 < r < bound for r in ratios)
    # §4.3: the noise's increment of group 2 over group 1 fits as well (13.8 rad/s), group 1 alone does not
    noise_ratio = np.sqrt(26.552**2 - 23.594**2) / np.sqrt(1.252**2 - 0.890**2)
    assert 13.0 < noise_ratio < bound < THESIS_GROUP1_RATIO
    # a 5 Hz ring would reach group 1's ratio only if the same 10/40-sample estimators ran at about 400 Hz
    for fs, lo, hi in ((200.0, 15.0, 16.0), (400.0, 26.0, 27.0)):
        cv = scipy.signal.savgol_coeffs(10, 1, deriv=1, delta=1 / fs, use="conv")
        ca = scipy.signal.savgol_coeffs(40, 2, deriv=2, delta=1 / fs, use="conv")
        r5 = abs(scipy.signal.freqz(ca, worN=[5.0], fs=fs)[1][0]) / abs(scipy.signal.freqz(cv, worN=[5.0], fs=fs)[1][0])
        assert lo < r5 < hi, fs
