"""A controller change keeps the tip deflection under a bound.

The rig's controller is configured by settings; here the input shaper
(OATF) is switched from its fixed design to the adaptive one, which re-designs
it from the DSP's identified first mode. The bound is the user's own
acceptance limit for the arm's vibration on the inspection loop.
"""

from __future__ import annotations

import numpy as np
import pytest

DEFLECTION_BOUND_IN = 0.3
"""Largest tip deflection the change may allow, either link (inches)."""


@pytest.mark.parametrize("oatf_mode", ["fixed", "adaptive"])
def test_shaper_change_keeps_deflection_bounded(rig, oatf_mode):
    rig.set("controller", oatf_mode=oatf_mode)
    record = rig.run(duration_s=8.0)

    assert record.error is None
    assert record.ticks == 8.0 * 200
    assert record.max_abs_deflection_in < DEFLECTION_BOUND_IN
    # the plant's own truth agrees with what the controller measured
    true_max = max(abs(d) for t in record.truth for d in t.deflections_in)
    assert true_max < DEFLECTION_BOUND_IN
    assert np.isfinite(record.columns["defl1_in"]).all()
