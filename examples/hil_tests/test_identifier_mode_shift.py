"""The identifier finds the payload's mode shift.

The arm starts with the 15.65 lb payload at its tip; at 20 s of simulated
time the plant's test port releases it and the first flexible mode rises.
The DSP's identified first mode must follow the plant's true one.
"""

from __future__ import annotations

import numpy as np
import pytest

RELEASE_S = 20.0


@pytest.mark.rig_settings(plant={"payload_attached": True}, dsp={"fft_width": 1024, "alpha": 0.05, "smoothing": "window=9"})
def test_identifier_follows_payload_release(rig):
    rig.plant.payload(attached=False, at_s=RELEASE_S)
    record = rig.run(duration_s=36.0)

    assert record.error is None
    assert any(e.kind == "payload" for e in record.events)
    t, identified = record.columns["t_s"], record.columns["f_id_hz"]
    truth_t = np.array([s.sim_time_s for s in record.truth])
    true_f1 = np.interp(t, truth_t, record.true_first_mode_hz())
    before, after = (t >= 14) & (t < RELEASE_S), t >= 30
    true_shift = np.median(true_f1[after]) - np.median(true_f1[before])
    found_shift = np.nanmedian(identified[after]) - np.nanmedian(identified[before])
    assert true_shift > 0.5, "releasing the payload raises the first mode"
    assert found_shift > 0.6 * true_shift
    assert np.nanmedian(identified[after]) == pytest.approx(np.median(true_f1[after]), rel=0.10)
