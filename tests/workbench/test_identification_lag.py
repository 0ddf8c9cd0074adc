"""The identification lag (:mod:`workbench.experiments.lib.identification_lag`) on a known delay: an identified
track that is the truth delayed by 3 s gives a 3-s alignment and 3-s transitions; an undelayed one gives 0."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workbench.experiments.lib.identification_lag import identification_lag, lag_figure

FS = 200.0
DELAY_S = 3.0


def _truth(t: np.ndarray) -> np.ndarray:
    """A first mode that rises from 4 Hz to 5 Hz and falls back, slowly (transitions of 1 Hz)."""
    return 4.0 + 0.5 * (1.0 - np.cos(2 * np.pi * t / 40.0))


def _track(delay_s: float):  # type: ignore[no-untyped-def]
    t = np.arange(int(60 * FS)) / FS
    f_id = _truth(t - delay_s)
    f_id[t < 10.0] = np.nan  # the identifier waits for a full history
    truth_t = np.arange(0.0, 60.0, 0.05)
    return identification_lag(t, f_id, truth_t, _truth(truth_t), max_lag_s=15.0, smooth_s=1.0, transition_hz=0.25), truth_t


def test_a_delayed_track_lags_by_its_delay() -> None:
    track, truth_t = _track(DELAY_S)
    assert track.t_first == pytest.approx(10.0)
    al = track.lag["alignment"]
    assert al["lag_s"] == pytest.approx(DELAY_S, abs=0.1)
    assert al["error_at_lag_hz"] < 0.01 < al["error_at_zero_hz"]
    finite = [x["lag_s"] for x in track.lag["transitions"] if math.isfinite(x["lag_s"])]
    assert finite and all(v == pytest.approx(DELAY_S, abs=0.2) for v in finite)
    assert track.lag["median_transition_lag_s"] == pytest.approx(DELAY_S, abs=0.2)
    assert lag_figure(track, truth_t, _truth(truth_t), 1.0).axes


def test_an_undelayed_track_does_not_lag() -> None:
    track, _ = _track(0.0)
    assert track.lag["alignment"]["lag_s"] == pytest.approx(0.0, abs=0.1)


def test_a_track_that_never_identified_is_refused() -> None:
    t = np.arange(100) / FS
    with pytest.raises(RuntimeError, match="never reported a pole"):
        identification_lag(t, np.full(t.size, np.nan), t, np.full(t.size, 4.0), 15.0, 1.0, 0.25)
