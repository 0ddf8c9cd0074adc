"""The experiments' shared analysis (workbench/experiments/lib): delays after a step against steps built with
a known delay, the replay's holding of batch estimates, the D/A's rounding noise, the loop of teeth, the
payload's stimulus."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.stimulus_eval import StimulusSource
from workbench.experiments.lib.arx_replay import held
from workbench.experiments.lib.dither_cost import DA_LSB_V, expected_sent_rms_v
from workbench.experiments.lib.etfe_smoothing import smoothing_window
from workbench.experiments.lib.identification_delay import series_delays, steady_share
from workbench.experiments.lib.teeth_loop import square_teeth_loop
from workbench.experiments.onrig.id_lag import payload_stimulus
from workbench.stimulus import Stimulus

FS = 200.0


def _step(t: np.ndarray, at: float, old: float, new: float) -> np.ndarray:
    return np.where(t < at, old, new)


@pytest.mark.parametrize("lag_s", [0.5, 1.7, 3.0])
def test_delays_of_a_delayed_step_are_its_delay(lag_s: float) -> None:
    t = np.arange(0.0, 40.0, 1.0 / FS)
    truth = _step(t, 15.0, 4.17, 4.56)
    rng = np.random.default_rng(1)
    f = _step(t, 15.0 + lag_s, 4.17, 4.56) * (1.0 + 0.004 * rng.standard_normal(t.size))  # noise well inside the 2 % band
    d = series_delays(t, f, truth, [15.0])
    (e,) = d["events"]
    step = 10 / FS  # the running median is taken on every 10th sample
    assert e["kind"] == "release" and e["step_pct"] == pytest.approx(100 * (4.56 - 4.17) / 4.17)
    assert e["started_on_the_old_side"]
    for key in ("settle_2pct_s", "stays_2pct_s", "delay_50pct_s"):
        assert e[key] == pytest.approx(lag_s, abs=step + 1e-9), key
    assert e["first_raw_in_band_s"] == pytest.approx(lag_s, abs=1.0 / FS + 1e-9)
    assert d["settled_events"] == 1 and d["median_rel_error_end"] < 0.01


def test_a_series_that_never_follows_is_infinite_and_a_wrong_start_is_nan() -> None:
    t = np.arange(0.0, 30.0, 1.0 / FS)
    truth = _step(t, 10.0, 4.56, 4.17)  # picked up: the mode steps down
    (e,) = series_delays(t, np.full(t.size, 4.56), truth, [10.0])["events"]
    assert e["kind"] == "attach" and math.isinf(e["settle_2pct_s"]) and math.isinf(e["delay_50pct_s"])
    (e,) = series_delays(t, np.full(t.size, 4.0), truth, [10.0])["events"]  # below both: never on the old side
    assert not e["started_on_the_old_side"] and math.isnan(e["delay_50pct_s"])


def test_steady_share_counts_the_time_within_the_band() -> None:
    t = np.arange(0.0, 40.0, 1.0 / FS)
    truth = np.full(t.size, 4.0)
    f = np.where((t > 20.0) & (t < 25.0), 4.4, 4.0)  # 5 s out of the band in the steady stretch 8..~39 s
    share = steady_share(t, f, truth, [0.0])
    assert share == pytest.approx(1.0 - 5.0 / (39.0 - 1.0 - 8.0), abs=0.01)


def test_held_estimates_start_two_batches_after_their_batch() -> None:
    per_batch = np.arange(5.0)
    h = held(per_batch, 7 * 20, 20)
    assert np.isnan(h[:40]).all()
    assert (h[40:60] == 0.0).all() and (h[60:80] == 1.0).all() and (h[120:] == 4.0).all()


def test_the_dither_as_sent_adds_the_d_a_rounding_noise() -> None:
    rng = np.random.default_rng(3)
    a = 0.01
    x = rng.uniform(-3.0, 3.0, 200_000)  # the PI's output: many LSBs, so the rounding error is uniform
    d = a * math.sqrt(2.0) * np.sin(2 * np.pi * 1.3 * np.arange(x.size) / FS)  # a dither of RMS a
    sent = np.round((x + d) / DA_LSB_V) * DA_LSB_V - x
    assert float(np.sqrt(np.mean(sent**2))) == pytest.approx(expected_sent_rms_v(a), rel=0.01)


def test_smoothing_window_keeps_the_width_in_hz() -> None:
    assert smoothing_window(2048) == 17 and smoothing_window(1024) == 9 and smoothing_window(512) == 5 and smoothing_window(64) == 5


def test_the_loop_of_teeth_closes_and_stays_on_one_side_of_its_base() -> None:
    teeth = ((3.0, 4.0), (2.0, 1.0))
    traj = square_teeth_loop((0.0, 0.0), (1.0, 0.0), teeth, speed_in_per_s=5.0, name="t", description="d")
    pts = [(w.x_in, w.y_in) for w in traj.waypoints]
    assert traj.closed and pts[0] == (0.0, 0.0) and pts[-1] == (3.0 + 2.4 + 2.0 + 1.6, 0.0)
    length = float(np.sum(np.hypot(*np.diff(np.array(pts), axis=0).T)))
    assert length == pytest.approx(2 * (4.0 + 1.0) + 3.0 + 2.4 + 2.0 + 1.6)
    assert min(y for _, y in pts) == 0.0 and max(y for _, y in pts) == 4.0


def test_the_payload_stimulus_releases_and_picks_up_at_the_events() -> None:
    _controller, plan = Stimulus(payload_stimulus([22.0, 42.0, 62.0]).profiles).plans()
    source = StimulusSource(plan)
    attached = {t: (not source.any_active("payload", t)) or source.value("payload", t) >= 0.5 for t in (21.995, 22.0, 41.995, 42.0, 61.995, 62.0, 90.0)}
    assert attached == {21.995: True, 22.0: False, 41.995: False, 42.0: True, 61.995: True, 62.0: False, 90.0: False}
