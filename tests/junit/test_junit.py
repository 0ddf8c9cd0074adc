"""``--junit FILE`` of timing-test, experiment and sweep, read back with junitparser
(a JUnit reader nobody here wrote): one case per check or run, value and limit as
properties, failure text, error and skip."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from junitparser.junitparser import Error, Failure, Skipped
from junitparser.xunit2 import JUnitXml

from workbench.cli import main
from workbench.experiments.framework import RunOutcome
from workbench.junit import CaseVerdict, SuiteVerdict, experiment_suite, sweep_suite, write_junit

ROOT = Path(__file__).resolve().parents[2]


def cases(path: Path) -> dict[str, object]:
    xml = JUnitXml.fromfile(str(path))
    return {case.name: case for suite in xml for case in suite}


def props(case: object) -> dict[str, str]:
    return {p.name: p.value for p in case.properties()}  # type: ignore[attr-defined]


def test_timing_test_writes_a_case_per_criterion(tmp_path: Path) -> None:
    """Under the interrupt-loss scenario past its late-batch fault (from 10 s) and a
    limit of 0 misses in a row the deadline criterion fails; the file says so."""
    junit = tmp_path / "timing.xml"
    code = main(
        ["timing-test", str(ROOT / "docs/scenarios/zenoh-interrupt-loss.yaml"), "--out", str(tmp_path / "r"),
         "--duration", "12", "--max-consecutive-misses", "0", "--junit", str(junit)]
    )  # fmt: skip
    assert code == 1
    report = json.loads((tmp_path / "r/report.json").read_text())
    got = cases(junit)
    assert set(got) == {c["name"] for c in report["criteria"]} | {"run verdict"}
    misses = got["consecutive deadline misses"]
    measured = next(c for c in report["criteria"] if c["name"] == "consecutive deadline misses")
    assert props(misses) == {"value": str(measured["value"]), "limit": "0", "unit": "batches", "judged": str(report["batches"])}
    assert measured["value"] > 0
    [failure] = misses.result  # type: ignore[attr-defined]
    assert isinstance(failure, Failure) and "exceeds the limit 0" in (failure.message or "")
    assert got["consecutive overruns"].is_passed  # type: ignore[attr-defined]
    for name in ("wakeup p99", "wakeup p99.9"):  # no wall clock in cosim: skipped, with the reason
        [skip] = got[name].result  # type: ignore[attr-defined]
        assert isinstance(skip, Skipped) and "n/a" in (skip.message or "")
        assert "value" not in props(got[name])
    [run] = got["run verdict"].result  # type: ignore[attr-defined]
    assert report["run_verdict"]["verdict"] == "FAIL" and props(got["run verdict"])["verdict"] == "FAIL"
    assert isinstance(run, Failure) and "timing FAIL: consecutive deadline misses" in (run.message or "")
    assert "interrupts lost (never came)" in (run.message or "")
    suite = next(iter(JUnitXml.fromfile(str(junit))))
    assert (suite.tests, suite.failures, suite.skipped, suite.errors) == (5, 2, 2, 0)


def test_experiment_writes_a_case_per_check(tmp_path: Path) -> None:
    junit = tmp_path / "exp.xml"
    assert main(["experiment", "fwhm-error", "--quick", "--no-progress", "--out", str(tmp_path / "e"), "--junit", str(junit)]) == 0
    checks = json.loads((tmp_path / "e/results.json").read_text())["checks"]
    got = cases(junit)
    assert [c["name"] for c in checks] == list(got)
    for check in checks:
        assert got[check["name"]].is_passed == check["passed"]  # type: ignore[attr-defined]
        assert props(got[check["name"]])["detail"] == check["detail"]


def test_experiment_failure_and_error_cases(tmp_path: Path) -> None:
    results = tmp_path / "results.json"
    results.write_text(json.dumps({"checks": [{"name": "f1 within 2 %", "passed": False, "detail": "3.1 % (limit 2 %)"}]}))
    failed = RunOutcome("probe", "checks failed", tmp_path, 1.5, results_path=results, checks_total=1)
    (tmp_path / "error.txt").write_text("Traceback: boom\n")
    broken = RunOutcome("broken", "error", tmp_path, 0.1, error="RuntimeError: boom")
    path = write_junit(tmp_path / "x.xml", [experiment_suite(failed), experiment_suite(broken)])
    xml = JUnitXml.fromfile(str(path))
    suites = {s.name: s for s in xml}
    [case] = list(suites["experiment.probe"])
    [failure] = case.result
    assert isinstance(failure, Failure) and failure.message == "f1 within 2 %: 3.1 % (limit 2 %)"
    [run] = list(suites["experiment.broken"])
    [error] = run.result
    assert isinstance(error, Error) and error.message == "RuntimeError: boom" and "Traceback: boom" in (error.text or "")
    assert (xml.tests, xml.failures, xml.errors) == (2, 1, 1)


def test_sweep_writes_a_case_per_run(tmp_path: Path) -> None:
    spec = tmp_path / "tiny.yaml"
    spec.write_text("name: tiny\nbase: {controller.duration_s: 1.0, batch_size: 20, dsp.fft_width: 256}\ngrid: {controller.oatf_mode: ['off', adaptive]}\n")
    junit = tmp_path / "sweep.xml"
    assert main(["sweep", str(spec), "--workers", "1", "--no-progress", "--out", str(tmp_path / "s"), "--junit", str(junit)]) == 0
    got = cases(junit)
    assert sorted(got) == ["0000 controller.oatf_mode=off", "0001 controller.oatf_mode=adaptive"]
    rows = [json.loads(line) for line in (tmp_path / "s/runs.jsonl").read_text().splitlines()]
    for row in rows:
        case = got[f"{row['index']:04d} controller.oatf_mode={row['controller.oatf_mode']}"]
        p = props(case)
        assert case.is_passed and p["ticks"] == str(row["ticks"]) and float(p["velocity_rms_1"]) == pytest.approx(row["velocity_rms_1"])  # type: ignore[attr-defined]
        assert "controller.duration_s" not in p  # shared settings go on the suite
    suite = next(iter(JUnitXml.fromfile(str(junit))))
    assert {p.name: p.value for p in suite.properties()}["controller.duration_s"] == "1.0"


def test_sweep_error_and_pending_runs() -> None:
    rows = [
        {"index": 0, "key": "a", "status": "error", "error": "ValueError: bad\n  more", "controller.kp": 1.0, "run_s": 0.2},
        {"index": 1, "key": "b", "status": "pending", "error": "", "controller.kp": 2.0},
    ]
    suite = sweep_suite("s", rows)
    assert [c.outcome for c in suite.cases] == ["error", "skipped"]
    assert suite.cases[0].message == "ValueError: bad" and suite.cases[0].name == "0000 controller.kp=1.0"


def test_non_finite_values_are_written(tmp_path: Path) -> None:
    path = write_junit(tmp_path / "n.xml", [SuiteVerdict("s", [CaseVerdict("c", "passed", properties={"value": float("nan"), "limit": 1})])])
    [case] = list(next(iter(JUnitXml.fromfile(str(path)))))
    assert props(case) == {"value": "nan", "limit": "1"}
