"""The OATF stage design on plain floats gives the bits of the numpy form of [3-32]."""

from __future__ import annotations

import math
import random

import numpy as np

from controller.oatf import OatfDesignError, _three_term, three_term_coefficients


def _numpy_form(frequency_hz: float, zeta: float, delay_s: float) -> np.ndarray:
    """[3-32] as it was written with three-element arrays (numpy's sum and division)."""
    wn = 2.0 * math.pi * frequency_hz
    wd = 2.0 * math.pi * frequency_hz * math.sqrt(1.0 - zeta * zeta)
    k = math.exp(-zeta * wn * delay_s)
    raw = np.array([1.0, -2.0 * math.cos(wd * delay_s) * k, k * k])
    return raw / float(raw.sum())


def test_plain_design_is_the_numpy_form_bit_for_bit() -> None:
    rng = random.Random(7)
    for _ in range(20000):
        f = rng.uniform(0.05, 99.0)
        z = rng.choice([0.0, rng.uniform(0.0, 0.999), 10 ** rng.uniform(-6, -0.01)])
        t = rng.choice([rng.uniform(1e-3, 2.0), rng.randint(1, 400) * 0.005])
        try:
            plain = _three_term(f, z, t)
        except OatfDesignError:
            continue
        want = _numpy_form(f, z, t)
        assert np.array(plain).tobytes() == want.tobytes(), (f, z, t)
        assert three_term_coefficients(f, z, t).tobytes() == want.tobytes()
