"""The experiments' OATF analysis (workbench/experiments/lib) against analytic references."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.checks import detected_within
from workbench.experiments.lib.identification_truth import BIN_HZ, identification_against_truth
from workbench.experiments.lib.oatf_costs import costs_against, run_costs
from workbench.experiments.lib.oatf_tracking import design_against_truth, design_changes, first_mode_over_run
from workbench.hil import RunRecord

TS = 0.005


def record(columns: dict[str, np.ndarray], f1: np.ndarray | None = None, f2: np.ndarray | None = None, zeta: float = 0.05) -> RunRecord:
    """A run of ``len(columns['t_s'])`` ticks whose truth (sampled at the ticks) has modes ``f1``, ``f2``."""
    t = columns["t_s"]
    truth: dict[str, np.ndarray] = {}
    if f1 is not None:
        modes = np.column_stack([f1, f1 * 2.5 if f2 is None else f2])
        truth = {"sim_time_s": t + TS, "modal_frequencies_hz": modes, "damping_ratios": np.full(modes.shape, zeta)}
    return RunRecord("cosim", None, t.size, float(t[-1]), {}, columns, [], [], [], {}, 0.0, truth_columns=truth)


def sine_run(amplitudes: tuple[float, float], f_hz: float = 4.0, seconds: float = 20.0) -> RunRecord:
    t = np.arange(int(seconds / TS)) * TS
    return record({"t_s": t, "defl1_in": amplitudes[0] * np.sin(2 * np.pi * f_hz * t), "defl2_in": amplitudes[1] * np.sin(2 * np.pi * f_hz * t)})


def test_the_velocity_cost_of_a_sine_is_its_derivatives_rms() -> None:
    # d/dt A sin(ωt) = Aω cos(ωt): RMS Aω/√2; the second derivative's RMS Aω²/√2 (at 0.5 Hz the
    # regressions' windows, 0.05 s and 0.2 s, are short against the period: their attenuation is below 0.3 %)
    f, amp = 0.5, (0.1, 0.2)
    c = run_costs(sine_run(amp, f))
    w = 2 * np.pi * f
    assert c["velocity_rms"] == pytest.approx([a * w / np.sqrt(2) for a in amp], rel=0.005)
    assert c["acceleration_rms"] == pytest.approx([a * w * w / np.sqrt(2) for a in amp], rel=0.005)


def test_a_run_at_half_the_amplitude_costs_half_of_its_baseline_over_any_mask() -> None:
    base, half = sine_run((0.1, 0.2)), sine_run((0.05, 0.1))
    for mask in (None, np.arange(4000) >= 2000, np.ones(9000, dtype=bool)):  # a mask longer than the run is cut to it
        e = costs_against(half, base, mask)
        assert e["velocity_pct"] == pytest.approx([50.0, 50.0]) and e["acceleration_pct"] == pytest.approx([50.0, 50.0])
        assert e["velocity_rms_in_s"] == run_costs(half, mask)["velocity_rms"]
    assert costs_against(base, run_costs(base))["velocity_pct"] == [100.0, 100.0]


def adaptive_run(step_s: float = 6.0) -> RunRecord:
    t = np.arange(4000) * TS
    f1 = 4.0 + 0.5 * np.sin(2 * np.pi * t / 20.0)
    oatf = np.where(t < step_s, 10.0, 4.0)
    return record({"t_s": t, "oatf_hz": oatf, "defl1_in": 0 * t, "defl2_in": 0 * t}, f1)


def test_design_changes_are_detected_where_the_design_moved() -> None:
    r = adaptive_run(6.0)
    res = detected_within(0.0, design_changes(r), float(r.t_s[-1]))
    assert res.passed and res.measured == pytest.approx(6.0)
    s = design_against_truth(r)
    assert s["first_change_s"] == pytest.approx(6.0) and s["design_changes"] == 1
    assert (s["min_hz"], s["max_hz"], s["median_hz_after_first_change"]) == (4.0, 10.0, 4.0)
    f1 = r.true_mode_hz(r.t_s, 0)
    after = r.t_s >= 6.0
    assert s["median_rel_error_after_first_change"] == pytest.approx(float(np.median(np.abs(4.0 - f1[after]) / f1[after])))
    # 10 Hz is never within 10 % of a 3.5-4.5 Hz mode; 4 Hz is wherever the mode is within 3.64-4.44 Hz
    assert s["time_within_10pct_of_true_f1"] == pytest.approx(np.mean(after & (np.abs(4.0 - f1) <= 0.1 * f1)))
    m = first_mode_over_run(r)
    assert m["mean_f1_hz"] == pytest.approx(4.0, abs=0.01) and m["variation_pct"] == pytest.approx(25.0, rel=0.01)


def test_a_design_that_never_moves_is_not_a_detection() -> None:
    r = adaptive_run(step_s=1e9)
    assert not detected_within(0.0, design_changes(r), float(r.t_s[-1])).passed
    assert np.isnan(design_against_truth(r)["first_change_s"])


def test_an_identification_two_seconds_late_is_within_a_bin_of_the_lagged_truth() -> None:
    # the truth ramps 3 -> 5 Hz over 40 s (0.05 Hz/s); an identifier 2 s late is 0.1 Hz off at every tick
    t = np.arange(8000) * TS
    f1 = 3.0 + 0.05 * t
    f_id = 3.0 + 0.05 * np.clip(t - 2.0, 0.0, None)
    cols = {"t_s": t, "f_id_hz": f_id, "f_id2_hz": 2.5 * f1 * 1.1, "zeta_id": np.full(t.size, 0.04), "oatf_hz": f_id}
    e = identification_against_truth(record(cols, f1, 2.5 * f1), settle_s=10.0, lag_s=4.0)
    assert e["f1_median_abs_error_hz"] == pytest.approx(0.1, abs=0.001)
    assert BIN_HZ == pytest.approx(0.0977, abs=1e-4) and e["f1_within_bin_of_lagged_truth"] == 1.0 and e["identified_share"] == 1.0
    assert e["f2_median_rel_error"] == pytest.approx(0.1) and e["zeta_median"] == pytest.approx(0.04) and e["true_zeta"] == 0.05
    # a memory of 1 s: the estimate is 0.05 Hz below the truth's last second, more than a bin of 0.02 Hz
    short = identification_against_truth(record(cols, f1, 2.5 * f1), settle_s=10.0, lag_s=1.0, bin_hz=0.02)
    assert short["f1_within_bin_of_lagged_truth"] == 0.0
