"""Named signal checks on a co-simulated run: tracking, deflection, the
identified mode, deadlines.

The run's set point is the thesis's inspection trajectory (the joints hold
for 3 s, then move). Each check returns a result with one line and a figure
(docs/signal-checks.md): in the JUnit XML each is a property of the test
(``check:follows_reference(phi_ref1, phi1)`` -> ``PASS measured=... limit=...``),
in pytest-html's report (``--html``) a figure. ``check(...)`` judges them
together, so a failing one does not hide the next.

Measured on the co-simulated rig (10 s, seed 0): each joint follows its set
point 65-70 ms behind with a largest error of about 0.006 and 0.009 rad after
that lag; the deflections stay under 0.2 in; the identified first mode is
within 3.5 % of the plant's true one from 7 s on (it settles on the first
mode between 6 and 7 s); no deadline is missed.
"""

from __future__ import annotations

import pytest

from workbench.checks import check, deadline_misses, follows_reference, mode_frequency_within, no_deadline_miss_streak, signal, stays_within

TRACKING_TOLERANCE_RAD = 0.012
"""Largest joint angle error once the joint's lag is taken out."""
MAX_LAG_S = 0.1
"""Largest lag of a joint behind its set point."""
DEFLECTION_BAND_IN = 0.3
"""Tip deflections stay within ±this, either link (inches, as the cameras read it)."""
MODE_TOLERANCE = 0.10
"""Identified first mode within this fraction of the true one, once identified."""
IDENTIFIED_FROM_S = 7.0
"""When the identifier has filled enough of its window to be held to the truth."""


@pytest.mark.rig_settings(dsp={"fft_width": 1024, "alpha": 0.05, "smoothing": "window=9"})
def test_joints_follow_and_the_identifier_finds_the_first_mode(rig):
    record = rig.run(duration_s=10.0)
    assert record.error is None

    check(
        follows_reference(signal(record, "phi_ref1"), signal(record, "phi1"), tolerance=TRACKING_TOLERANCE_RAD, max_lag_s=MAX_LAG_S),
        follows_reference(signal(record, "phi_ref2"), signal(record, "phi2"), tolerance=TRACKING_TOLERANCE_RAD, max_lag_s=MAX_LAG_S),
        stays_within(signal(record, "defl1_in"), -DEFLECTION_BAND_IN, DEFLECTION_BAND_IN),
        stays_within(signal(record, "defl2_in"), -DEFLECTION_BAND_IN, DEFLECTION_BAND_IN),
        mode_frequency_within(signal(record, "f_id_hz"), signal(record, "truth.modal_frequencies_hz[0]"), rel_tol=MODE_TOLERANCE, from_s=IDENTIFIED_FROM_S),
        no_deadline_miss_streak(deadline_misses(record), 1),
    )
