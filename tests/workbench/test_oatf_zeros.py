"""The OATF's zeros and notch against scipy.signal.tf2zpk and the stage's design."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from controller.oatf import design_stage, design_stage_continuous
from workbench.experiments.lib.oatf_zeros import abs_at_pole, notch, zeros, zeros_hz


def test_zeros_are_scipys() -> None:
    s = design_stage(4.4, 0.09, 1 / 200)
    b = np.zeros(2 * s.delay_samples + 1)
    b[[0, s.delay_samples, 2 * s.delay_samples]] = s.coefficients
    z, _, _ = ss.tf2zpk(b, [1.0])
    assert np.allclose(np.sort_complex(zeros(s)), np.sort_complex(z))
    up = zeros_hz(s)
    assert [d["frequency_hz"] for d in up] == sorted(d["frequency_hz"] for d in up)
    assert len(up) == int(np.sum(np.angle(z) >= -1e-12))


def test_the_discrete_design_cancels_its_mode() -> None:
    for zeta in (0.0, 0.02, 0.09):
        assert abs_at_pole(design_stage(51.0, zeta, 1 / 500), 51.0, zeta) < 1e-9
    assert abs_at_pole(design_stage_continuous(51.0, 0.09, 1 / 500), 51.0, 0.09) > 0.01


def test_notch() -> None:
    f, m = notch(design_stage(51.0, 0.0, 1 / 500), 51.0, 250.0, 2001)
    assert f == pytest.approx(51.0, abs=1e-3) and m < 1e-6
    f, _ = notch(design_stage_continuous(51.0, 0.0, 1 / 500), 51.0, 250.0, 2001)
    assert f == pytest.approx(62.5, abs=0.01)  # coefficients from T1 with taps at n1 = 4: |F| ∝ cos²(π f / 125)
