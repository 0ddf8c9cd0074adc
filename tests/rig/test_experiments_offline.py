"""The experiment framework and the offline experiments (quick mode): report structure and physics."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from workbench.cli import main as cli_main
from workbench.experiments import (
    Experiment,
    UnknownExperimentError,
    framework,
    get_experiment,
    list_experiments,
    run_all,
    run_experiment,
)

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
OFFLINE = ("oatf-response", "fwhm-error", "vrm", "simulation")


def _run(name: str, out: Path, seed: int = 0) -> dict:
    outcome = run_experiment(name, out, quick=True, seed=seed, show_progress=False, raise_errors=True)
    assert outcome.status == "ok", outcome
    return outcome.results()


def _check_structure(out: Path, results: dict, headings: list[str], result_keys: list[str]) -> str:
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.startswith("# ")
    for h in headings:
        assert f"\n## {h}" in report, f"missing heading {h!r}"
    assert "| --- |" in report or "| ---: |" in report  # at least one table
    assert "## Comparison with the thesis" in report and "## Checks" in report
    assert results["figures"], "no figures"
    for fig in results["figures"]:
        png = out / fig
        assert png.is_file() and png.read_bytes()[:8] == PNG_MAGIC, fig
        assert f"]({fig})" in report, f"figure {fig} not embedded"
    for key in ("experiment", "title", "section", "meta", "results", "checks", "thesis_comparison", "figures"):
        assert key in results
    for key in result_keys:
        assert key in results["results"], key
    assert results["meta"]["quick"] is True and results["meta"]["seed"] == 0
    assert all(c["passed"] for c in results["checks"]), results["checks"]
    return report


# ------------------------------------------------------------------ registry and CLI


def test_offline_experiments_are_registered() -> None:
    names = [e.name for e in list_experiments()]
    for name in OFFLINE:
        assert name in names
        exp = get_experiment(name)
        assert exp.section and exp.description and "\n" not in exp.description
        assert not exp.needs_rig
    assert framework.broken_modules() == {}


def test_list_output(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["experiment", "--list"]) == 0
    out = capsys.readouterr().out
    for name in (*OFFLINE, "all"):
        assert name in out
    assert "App. B" in out and "§4.3" in out


def test_ralf_hil_knows_the_experiment_command(capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    assert main(["experiment", "--list"]) == 0
    assert "oatf-response" in capsys.readouterr().out


def test_unknown_name_is_a_clear_error(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert cli_main(["experiment", "vrn", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "unknown experiment 'vrn'" in err and "did you mean 'vrm'" in err and "fwhm-error" in err
    assert not (tmp_path / "x").exists()
    with pytest.raises(UnknownExperimentError, match="unknown experiment 'nope'"):
        run_experiment("nope", tmp_path / "y")
    assert cli_main(["experiment"]) == 2


def test_registry_rejects_bad_and_duplicate_names() -> None:
    list_experiments()  # discovery first, so that 'vrm' is taken
    with pytest.raises(ValueError):
        framework.experiment("Bad_Name", section="x", description="y")
    with pytest.raises(ValueError):
        framework.experiment("all", section="x", description="y")
    with pytest.raises(ValueError, match="already registered"):

        @framework.experiment("vrm", section="x", description="y")
        def other(ctx):  # noqa: ANN001, ANN202
            raise AssertionError


def test_all_reports_errors_in_the_index(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def boom(ctx: framework.ExperimentContext):  # noqa: ANN202
        raise RuntimeError("deliberate failure")

    def tiny(ctx: framework.ExperimentContext):  # noqa: ANN202
        rep = ctx.report("tiny")
        rep.results["x"] = float("nan")
        rep.check("always", True)
        return rep

    monkeypatch.setitem(framework._REGISTRY, "zz-boom", Experiment("zz-boom", "§0", "fails", boom))
    monkeypatch.setitem(framework._REGISTRY, "zz-tiny", Experiment("zz-tiny", "§0", "works", tiny))
    monkeypatch.setitem(framework._BROKEN, "workbench.experiments.zz_broken", "ImportError: no such thing")
    outcomes, index = run_all(tmp_path, names=["zz-boom", "zz-tiny"], show_progress=False)
    assert [o.status for o in outcomes] == ["error", "ok"]
    text = index.read_text(encoding="utf-8")
    assert "error: RuntimeError: deliberate failure" in text
    assert "[report](zz-tiny/report.md)" in text and "[error](zz-boom/error.txt)" in text
    assert "workbench.experiments.zz_broken" in text
    assert "deliberate failure" in (tmp_path / "zz-boom" / "error.txt").read_text(encoding="utf-8")
    data = json.loads((tmp_path / "index.json").read_text(encoding="utf-8"))
    assert [e["status"] for e in data["experiments"]] == ["error", "ok"]
    assert json.loads((tmp_path / "zz-tiny" / "results.json").read_text())["results"]["x"] == "nan"


def test_an_experiment_checking_nothing_or_every_item_of_nothing_does_not_pass(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def nothing(ctx: framework.ExperimentContext):  # noqa: ANN202
        return ctx.report("nothing")

    def every_of_none(ctx: framework.ExperimentContext):  # noqa: ANN202
        rep = ctx.report("every of none")
        assert rep.check_every("every download agrees", [True, True, True], "15 s, 20 s, 25 s")
        assert not rep.check_every("every lag positive", [], "none measurable")
        assert not rep.check_every("at least three runs", [True, True], at_least=3)
        assert not rep.check_every("every one and the rest", [True], also=False)
        return rep

    monkeypatch.setitem(framework._REGISTRY, "zz-nothing", Experiment("zz-nothing", "§0", "checks nothing", nothing))
    monkeypatch.setitem(framework._REGISTRY, "zz-none", Experiment("zz-none", "§0", "checks over nothing", every_of_none))
    outcomes, _ = run_all(tmp_path, names=["zz-nothing", "zz-none"], show_progress=False)
    assert [(o.status, o.checks_passed, o.checks_total) for o in outcomes] == [("checks failed", 0, 0), ("checks failed", 1, 4)]
    checks = {c["name"]: c for c in json.loads((tmp_path / "zz-none" / "results.json").read_text())["checks"]}
    assert checks["every download agrees"] == {"name": "every download agrees", "passed": True, "detail": "3 of 3; 15 s, 20 s, 25 s"}
    assert checks["every lag positive"]["detail"] == "too few to judge: 0 (at least 1); none measurable"
    assert checks["at least three runs"]["detail"] == "too few to judge: 2 (at least 3)"
    assert checks["every one and the rest"]["detail"] == "1 of 1" and not checks["every one and the rest"]["passed"]


def test_experiment_all_over_no_experiment_does_not_pass(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    framework.discover()
    monkeypatch.setattr(framework, "_REGISTRY", {})
    assert main(["experiment", "all", "--out", str(tmp_path), "--no-progress"]) == 1
    assert "0 of 0 experiments ok: none ran, nothing to pass" in capsys.readouterr().err


# ------------------------------------------------------------------ offline experiments


def test_oatf_response(tmp_path: Path) -> None:
    res = _run("oatf-response", tmp_path)
    report = _check_structure(
        tmp_path,
        res,
        ["1. Integer delay versus continuous delay: 51 Hz at 500 Hz (Figs. 3.7, 3.8)", "2. OATF for a 4.4 Hz mode"],
        ["example_51hz", "arm_4p4hz"],
    )
    assert "| design | coefficients a0, a1, a2 | \\|F(51 Hz)\\|" in report
    ex = res["results"]["example_51hz"]
    assert ex["n1_samples"] == 4
    assert ex["abs_F_at_51hz"]["discrete"] < 1e-9
    assert ex["abs_F_at_51hz"]["continuous"] > 0.05
    assert ex["notch_continuous_hz"] == pytest.approx(62.5, abs=0.01)  # cos^2(pi f / 125) vanishes at 62.5 Hz
    assert ex["notch_discrete_hz"] == pytest.approx(51.0, abs=1e-3)
    arm = res["results"]["arm_4p4hz"]
    for z in ("0.09", "0.01"):
        assert arm["designs"][z]["abs_F_at_pole"] < 1e-9
        assert arm["sensitivity"][z]["mode_zeta_equals_design"]["V_at_design"] < 1e-9
    # the 0.01 design tolerates less frequency error on the arm's 0.09 mode
    s = arm["sensitivity"]
    assert s["0.01"]["mode_zeta_0.09"]["V_below_5pct_width"] < s["0.09"]["mode_zeta_0.09"]["V_below_5pct_width"]


def test_fwhm_error(tmp_path: Path) -> None:
    res = _run("fwhm-error", tmp_path)
    _check_structure(tmp_path, res, ["1. [B.1] against the exact width (Fig. B.1)", "2. On the identifier's grid"], ["analytic", "grid"])
    a = res["results"]["analytic"]
    zetas, err = a["zeta"], a["rel_error_true_wn"]
    assert all(abs(e) < 0.01 for z, e in zip(zetas, err) if z < 0.098)
    assert all(e2 > e1 for e1, e2 in zip(err, err[1:]))  # growing with zeta
    assert 0.095 < a["crossing_1pct_true_wn"] < 0.1
    assert a["crossing_1pct_peak_wn"] < a["crossing_1pct_true_wn"]
    assert a["exact_inversion_max_rel_error"] < 1e-9


def test_vrm(tmp_path: Path) -> None:
    res = _run("vrm", tmp_path)
    report = _check_structure(tmp_path, res, ["Errors over noise draws"], ["monte_carlo", "example_draw", "truth"])
    assert "| noise | method |" in report
    lv = res["results"]["monte_carlo"]["levels"]
    assert set(lv) == {"SNR 1e4", "0.1 %", "1 %", "10 %"}
    for m in ("vrm_avg", "vrm_robust"):
        assert lv["SNR 1e4"][m]["frequency"]["max_abs_rel_error"] < 0.01
        assert lv["SNR 1e4"][m]["damping"]["max_abs_rel_error"] < 0.01
    # errors grow with noise, and the identifier's VRM damping beats FWHM at 10 %
    med = [lv[k]["vrm_robust"]["damping"]["median_abs_rel_error"] for k in ("0.1 %", "1 %", "10 %")]
    assert med == sorted(med)
    assert lv["10 %"]["vrm_robust"]["damping"]["median_abs_rel_error"] < lv["10 %"]["fwhm"]["damping"]["median_abs_rel_error"]
    assert lv["10 %"]["vrm_robust"]["damping"]["within_order_of_magnitude"] >= 0.9


def test_vrm_is_deterministic_per_seed(tmp_path: Path) -> None:
    a = _run("vrm", tmp_path / "a", seed=3)["results"]
    b = _run("vrm", tmp_path / "b", seed=3)["results"]
    assert a == b


def test_simulation(tmp_path: Path) -> None:
    res = _run("simulation", tmp_path)
    report = _check_structure(tmp_path, res, ["Model", "Results", "Sensitivity to the assumed actuator gain"], ["model", "trajectory", "groups", "designs"])
    for g in (1, 2, 3, 4):
        assert f"*Group {g}:" in report
    assert "| design | link 1 vel (in/s) | % | link 2 vel (in/s) | % |" in report
    groups = res["results"]["groups"]
    assert set(groups) == {"group1", "group2", "group3", "group4"}

    def vel(g: int, d: str) -> list[float]:
        return groups[f"group{g}"]["designs"][d]["velocity_rms_in_s"]

    def pct(g: int, d: str) -> list[float]:
        return groups[f"group{g}"]["designs"][d]["velocity_pct_of_unfiltered"]

    for link in (0, 1):
        assert vel(1, "OATF 5 Hz")[link] < vel(1, "unfiltered")[link]
        assert pct(1, "OATF 5 Hz")[link] < 50.0
        assert 90.0 < pct(1, "OATF 50 Hz")[link] < 110.0
        assert pct(2, "OATF 5 Hz")[link] > pct(1, "OATF 5 Hz")[link]  # noise bypasses the filter
    assert groups["group1"]["designs"]["unfiltered"]["velocity_pct_of_unfiltered"] == pytest.approx([100.0, 100.0])
    assert res["results"]["model"]["zoh_vs_10_substeps_max_abs_dev"] < 1e-10
    # Simulink band-limited white noise: the thesis's 1.41e-4 rad is sqrt(P / 0.1 s); at the 5 ms sample time sqrt(20) more
    assert math.isclose(res["results"]["trajectory"]["noise_quoted_std_rad"], 1.41e-4, rel_tol=0.01)
    assert math.isclose(res["results"]["trajectory"]["noise_std_used_rad"], 1.41e-4 * math.sqrt(20), rel_tol=0.01)
    assert res["results"]["designs"]["group3/OATF 50 Hz"]["delay_samples"] == res["results"]["designs"]["group2/OATF 50 Hz"]["delay_samples"] == 2
    assert (tmp_path / "records" / "simulation_g1_g2.npz").is_file()
    # the acceleration read three ways: only the 200 Hz estimators give the noise's ratio (13.8), none group 1's (26.5) with it
    rd = res["results"]["acceleration_readings"]
    assert rd["estimators_200hz"]["group1_ratio_rad_s"] < 16.3
    assert abs(rd["estimators_200hz"]["noise_part_ratio_rad_s"] / rd["thesis"]["noise_part_ratio_rad_s"] - 1.0) < 0.15
    assert rd["estimators_400hz"]["group1_ratio_rad_s"] > 22.0 and rd["estimators_400hz"]["noise_part_ratio_rad_s"] > 20.0
    assert rd["model_state_derivatives"]["noise_part_ratio_rad_s"] > 50.0


def test_simulation_fine_log_is_the_same_run_sampled_finer() -> None:
    from workbench.experiments.lib.velocity_feedback_arm import SimulationModel, simulate

    model = SimulationModel()
    t = np.arange(400) * model.sample_period_s
    sp = np.stack([np.stack([1.2 + 0.05 * np.sin(2 * np.pi * 0.7 * t), 0.8 + 0.04 * np.minimum(t, 1.0)], axis=1)])
    coarse = simulate(model, sp)
    fine = simulate(model, sp, log_substeps=2)
    assert np.allclose(fine["deflection_fine_in"][:, ::2], coarse["deflection_in"], rtol=0, atol=1e-12)
    assert np.allclose(fine["deflection_in"], coarse["deflection_in"], rtol=0, atol=1e-12)
    # the model's own derivative equals the slope of its own deflection between sub-samples
    slope = np.diff(fine["deflection_fine_in"][0], axis=0) / (model.sample_period_s / 2)
    central = 0.5 * (slope[1::2] + slope[2::2])  # at the coarse samples 1 .. n-1
    rate = coarse["deflection_rate_in_s"][0, 1:]
    assert np.allclose(central, rate, atol=0.02 * np.abs(rate).max())
