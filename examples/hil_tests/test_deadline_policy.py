"""A deadline policy holds under a link fault.

From 8 s to 12 s of simulated time every DSP interrupt is lost in a 0.5 s
burst once a second (a fault on the controller-DSP link). With
``policies=deadline=degrade`` and the OATF tuning's ``fallback=fixed`` the controller must
keep running to the end, count the missed deadlines, fall back to the
shaper's fixed design while the link is out, and adapt again once it is back.
"""

from __future__ import annotations

import numpy as np
import pytest

OUTAGE = {
    "name": "interrupt-outage",
    "seed": 1,
    "faults": [{"link": "zenoh", "kinds": ["interrupt"], "start_s": 8, "stop_s": 12, "outage": {"every_s": 1.0, "length_s": 0.5}}],
}
FIXED_DESIGN_HZ = 4.4


@pytest.mark.rig_settings(
    controller={"oatf_mode": "adaptive", "policies": "deadline=degrade", "oatf": {"fallback": "fixed", "frequency_hz": FIXED_DESIGN_HZ}},
    dsp={"fft_width": 1024, "alpha": 0.05, "smoothing": "window=9"},
)
@pytest.mark.rig_faults(OUTAGE)
def test_degrade_policy_holds_under_interrupt_outage(rig):
    record = rig.run(duration_s=14.0)

    assert record.error is None, "the degrade policy must not stop the run"
    assert record.ticks == 14.0 * 200
    assert record.health["controller"].counters["episodes_deadline"] > 0
    t, shaper = record.columns["t_s"], record.columns["oatf_hz"]
    before, during, after = (t >= 6) & (t < 8), (t >= 8) & (t < 12), t >= 13.5
    assert not np.any(shaper[before] == FIXED_DESIGN_HZ), "adapted before the fault"
    assert np.any(shaper[during] == FIXED_DESIGN_HZ), "fell back to the fixed design during the outage"
    assert not np.any(shaper[after] == FIXED_DESIGN_HZ), "adapts again once the link is back"
