"""The on-rig experiments (quick mode): report structure and physics; the laps and costs they share."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from workbench.experiments import framework, get_experiment, list_experiments, run_experiment
from workbench.experiments.analysis import costs_over
from workbench.laps import lap_seconds

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ONRIG = ("verify", "pi-spectrogram", "battery", "reduced-damping", "id-lag")


def _run(name: str, out: Path) -> dict:
    outcome = run_experiment(name, out, quick=True, seed=0, show_progress=False, raise_errors=True)
    results = outcome.results()
    assert outcome.status == "ok", [c for c in results.get("checks", []) if not c["passed"]]
    return results


def _check_structure(out: Path, results: dict, headings: list[str], result_keys: list[str]) -> str:
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.startswith("# ")
    for h in headings:
        assert f"\n## {h}" in report, f"missing heading {h!r}"
    assert "| ---: |" in report  # at least one numeric table
    assert "## Comparison with the thesis" in report and "## Checks" in report and "## Files" in report
    assert results["figures"], "no figures"
    for fig in results["figures"]:
        png = out / fig
        assert png.is_file() and png.read_bytes()[:8] == PNG_MAGIC, fig
        assert f"]({fig})" in report, f"figure {fig} not embedded"
    for key in ("experiment", "title", "section", "meta", "results", "checks", "thesis_comparison", "figures", "attachments"):
        assert key in results
    for key in result_keys:
        assert key in results["results"], key
    meta = results["meta"]
    assert meta["quick"] is True and meta["seed"] == 0 and meta["needs_rig"] is True and meta["mode"] == "cosim"
    assert all(c["passed"] for c in results["checks"]), results["checks"]
    for att in results["attachments"]:
        assert (out / att["path"]).is_file(), att
    return report


# ------------------------------------------------------------------ registry


def test_onrig_experiments_are_registered() -> None:
    names = [e.name for e in list_experiments()]
    for name in ONRIG:
        assert name in names
        exp = get_experiment(name)
        assert exp.needs_rig and exp.section and "\n" not in exp.description
        assert exp.module.startswith("workbench.experiments.onrig.")
    assert not [m for m in framework.broken_modules() if ".onrig" in m]


# ------------------------------------------------------------------ shared


def test_lap_seconds_match_the_thesis() -> None:
    assert lap_seconds(5.0) == pytest.approx(42.0, abs=0.5)
    assert lap_seconds(4.0) == pytest.approx(51.0, abs=1.0)


def test_costs_over_a_mask_equal_the_whole_run_costs() -> None:
    from controller.metrics import rms_costs

    rng = np.random.default_rng(1)
    d = np.cumsum(rng.standard_normal((2000, 2)), axis=0) * 1e-3
    whole = costs_over(d, np.ones(2000, dtype=bool))
    ref = rms_costs(d)
    assert np.allclose(whole["velocity_rms"], ref.velocity_rms)
    assert np.allclose(whole["acceleration_rms"], ref.acceleration_rms)
    part = costs_over(d, np.arange(2000) >= 1000)
    assert not np.allclose(part["velocity_rms"], whole["velocity_rms"])


# ------------------------------------------------------------------ experiments


@pytest.mark.timeout(120)
def test_verify_quick(tmp_path: Path) -> None:
    out = tmp_path / "verify"
    results = _run("verify", out)
    _check_structure(
        out, results, ["Run", "Implementation check (§4.1.1)", "Algorithm check (§4.1.2)"], ["implementation", "algorithm", "summary", "spectra_last"]
    )
    r = results["results"]
    # the DSP's downloads and the SciPy recomputation agree to rounding
    assert r["summary"]["worst_median_rel_diff"] < 1e-9
    assert r["summary"]["worst_max_rel_diff"] < 1e-6
    assert all(row["end_is_a_batch_end"] for row in r["implementation"])
    assert r["batches"]["reconstructed"] == r["batches"]["sent_by_controller"]
    # the Blackman-Tukey estimate is rougher than the on-line one at the FFT's resolution: in most
    # paths (the full run: 14 of 15 estimates); the weak link-2 paths (its camera sees the link's
    # bending only, a quarter of its deflection near the top) may be as rough in one 20 s quick run
    smoother = 0
    for name in ("H11", "H12", "H21", "H22", "Htot"):
        rough = r["algorithm"]["downloads"][-1][name]["roughness_db"]
        smoother += rough["online"] < rough["bt_half_N"]
        assert rough["online"] < rough["unsmoothed"]
    assert smoother >= 4


@pytest.mark.timeout(120)
def test_pi_spectrogram_quick(tmp_path: Path) -> None:
    out = tmp_path / "pis"
    results = _run("pi-spectrogram", out)
    _check_structure(out, results, ["Run", "Spectrograms", "Identification lag"], ["lag", "apex", "clutter", "downloads"])
    r = results["results"]
    assert r["downloads"]["with_estimate"] >= 2
    al = r["lag"]["alignment"]
    assert 0 < al["lag_s"] < r["lag"]["max_lag_searched_s"]
    assert al["error_at_lag_hz"] < al["error_at_zero_hz"]
    # the plain deflection spectrogram carries the trajectory's low-frequency motion
    assert r["clutter"]["plain_median_share_below_2hz"] > r["clutter"]["htot_median_share_below_2hz"]
    assert r["first_estimate_s"] >= 2048 / 200.0
    # the thesis's ETFE next to the transient-fit variant, both measured against the ground truth
    errors = r["identifiers"]["errors"]
    assert set(errors) == {"pi_loop", "pi_loop_etfe_transient"}  # quick: Welch and ARX run in full mode only
    assert all(0 <= e["whole"]["median_rel_f_error"] < 1 for e in errors.values())
    # the transient fit's damping is nearer the plant's than the thesis's VRM on the averaged spectrum
    z_vrm, z_fit = (abs(errors[k]["away"]["median_zeta"] / errors[k]["away"]["true_zeta"] - 1) for k in ("pi_loop", "pi_loop_etfe_transient"))
    assert z_fit < 0.25 < z_vrm


@pytest.mark.timeout(120)
def test_battery_quick_tuned_oatf_lowers_vibration(tmp_path: Path) -> None:
    out = tmp_path / "battery"
    results = _run("battery", out)
    _check_structure(out, results, ["Runs", "Costs"], ["groups"])
    g = results["results"]["groups"]["5in_s_nopayload"]
    assert 3.5 < g["right_hz"] < 4.7  # the mean true first mode, from the plant record of run (a)
    a, b = g["configs"]["a"], g["configs"]["b"]
    assert b["settings"] == {"oatf_mode": "fixed", "oatf": {"frequency_hz": pytest.approx(g["right_hz"], abs=1e-3), "damping": 0.09}}
    for link in (0, 1):
        assert b["velocity_rms_in_s"][link] < a["velocity_rms_in_s"][link]
        assert b["velocity_pct"][link] < 100.0
        assert a["velocity_pct"][link] == pytest.approx(100.0)


@pytest.mark.timeout(120)
def test_reduced_damping_quick(tmp_path: Path) -> None:
    out = tmp_path / "rd"
    results = _run("reduced-damping", out)
    _check_structure(out, results, ["Runs", "Costs"], ["costs", "adaptation", "apex"])
    r = results["results"]
    # the adaptive runs follow the recursive ARX, whose first poles come before the ETFE's history is full
    assert results["results"]["runs"]["adaptive"]["settings"]["dsp"]["identifier"] == "arx"
    assert r["adaptation"]["design_changes"] > 0 and 0 < r["adaptation"]["first_change_s"] < 18.0
    late = r["costs"]["after the first adaptation"]
    for link in (0, 1):
        assert late["adaptive"]["velocity_pct"][link] < late["fixed10"]["velocity_pct"][link]
    assert r["costs"]["whole run"]["samples"] > r["costs"]["apex, whole run"]["samples"] > 0


@pytest.mark.timeout(120)
def test_id_lag_quick(tmp_path: Path) -> None:
    out = tmp_path / "idlag"
    results = _run("id-lag", out)
    _check_structure(out, results, ["Runs"], ["settings", "trajectory", "events_s", "best_setting"])
    r = results["results"]
    d = r["settings"]["n1024_a0p05"]
    assert d["events_applied_s"] == pytest.approx(r["events_s"], abs=0.06)
    (e,) = d["events"]
    assert e["kind"] == "release" and e["step_pct"] > 4.0  # releasing the payload raises the first mode
    assert e["started_on_the_old_side"]
    assert 0 < e["delay_50pct_s"] < math.inf
    assert 0 < e["settle_2pct_s"] < math.inf
    assert e["delay_50pct_s"] <= e["settle_2pct_s"]
    assert e["settle_2pct_s"] <= e["stays_2pct_s"]  # staying up to the next event is the stricter reading
    # the DSP's ARX replayed from the record is the DSP's own, and with a reset at the event it can be compared
    rp = r["arx_replay"]
    assert rp["max_difference_to_the_record_hz"] <= 1e-9
    assert rp["as_run"]["median_settle_2pct_s"] == pytest.approx(r["settings"]["arx"]["median_settle_2pct_s"], abs=0.2)
    assert set(rp) >= {"reset_at_the_event", "change_detection", "change_alarms_s"}
    # the bank of a calibration run (another noise seed, its event 10 s later) carried in: reported, checked in full runs
    assert rp["carried_bank"]["events_s"] == [r["events_s"][0] + 10.0] and rp["carried_bank"]["seed"] != d["run"]["settings"]["plant"]["seed"]
    assert len(rp["regime_bank_carried"]["events"]) == 1
    assert (out / "records" / "idlag_trajectory.json").is_file()
    # the dithered ARX run: the D/A carried the dither, and it made the links move more (its cost)
    (dd,) = r["dither"]["runs"]
    assert dd["amplitude_v"] == 0.01
    assert dd["sent_rms_v"] == pytest.approx([0.01, 0.01], rel=0.2)
    assert all(x > 1.0 for x in dd["velocity_ratio"])
    assert dd["arx"]["max_difference_to_the_record_hz"] <= 1e-9
