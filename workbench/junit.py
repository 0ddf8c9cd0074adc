"""Verdicts as JUnit XML, the file CI systems read (``--junit FILE`` of
``ralf-hil timing-test``, ``experiment`` and ``sweep``).

One ``<testsuite>`` per command (per experiment for ``experiment all``),
one ``<testcase>`` per check or run: its measured value, limit and unit as
``<property>`` elements, a ``<failure>`` with the check's text when it
failed, an ``<error>`` when the run could not be made, ``<skipped>`` when
the check does not apply (e.g. wake-up latency in a mode without a wall
clock). Written with ``junitparser``'s xunit2 flavour (the Jenkins xunit
``junit-10.xsd`` layout pytest also writes).
"""

from __future__ import annotations

import math
import socket
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

from junitparser.junitparser import Error, Failure, Skipped
from junitparser.xunit2 import JUnitXml, TestCase, TestSuite

Outcome = Literal["passed", "failed", "error", "skipped"]


@dataclass(frozen=True)
class CaseVerdict:
    """One check or run as a JUnit test case."""

    name: str
    outcome: Outcome
    message: str = ""
    """The failure, error or skip text (empty when passed)."""
    properties: Mapping[str, Any] = field(default_factory=dict)
    """Measured value, limit, unit, settings: written as ``<property name= value=>``."""
    time_s: float | None = None
    detail: str = ""
    """Longer text inside the failure/error element (a traceback)."""


@dataclass(frozen=True)
class SuiteVerdict:
    name: str
    cases: Sequence[CaseVerdict]
    properties: Mapping[str, Any] = field(default_factory=dict)
    time_s: float | None = None


def _text(value: Any) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return "" if value is None else str(value)


def _case(classname: str, verdict: CaseVerdict) -> TestCase:
    case = TestCase(verdict.name, classname=classname, time=verdict.time_s if verdict.time_s is not None else 0.0)
    for key, value in verdict.properties.items():
        if value is not None:  # no measurement: no property (the skip says why)
            case.add_property(str(key), _text(value))
    if verdict.outcome == "failed":
        result: Any = Failure(verdict.message, "AssertionError")
    elif verdict.outcome == "error":
        result = Error(verdict.message, "RunError")
    elif verdict.outcome == "skipped":
        result = Skipped(verdict.message)
    else:
        return case
    if verdict.detail:
        result.text = verdict.detail
    case.result = [result]
    return case


def write_junit(path: str | Path, suites: Iterable[SuiteVerdict], classname_prefix: str = "ralf-hil") -> Path:
    """Write ``suites`` as one JUnit XML file (``<testsuites>`` root)."""
    xml = JUnitXml()
    stamp = datetime.now(UTC).isoformat(timespec="seconds")
    timed: list[tuple[TestSuite, float]] = []
    for s in suites:
        suite = TestSuite(s.name)
        suite.timestamp = stamp
        suite.hostname = socket.gethostname()
        for key, value in s.properties.items():
            suite.add_property(str(key), _text(value))
        for verdict in s.cases:
            suite.add_testcase(_case(f"{classname_prefix}.{s.name}", verdict))
        xml.add_testsuite(suite)
        if s.time_s is not None:
            timed.append((suite, round(float(s.time_s), 3)))
    xml.update_statistics()
    for suite, seconds in timed:  # the command's wall time, not the sum of its cases'
        suite.time = seconds
    xml.time = round(sum(float(suite.time or 0.0) for suite in xml), 3)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    xml.write(str(out), pretty=True)
    return out


# --- the commands' verdicts ------------------------------------------------------------------


def timing_suite(report: Mapping[str, Any]) -> SuiteVerdict:
    """``ralf-hil timing-test``'s report (:func:`workbench.timing_test.report.evaluate` plus the
    run's facts): one case per criterion, and an error case when the run itself failed."""
    cases = []
    for c in report["criteria"]:
        verdict = str(c["verdict"])
        props = {"value": c["value"], "limit": c["limit"], "unit": c["unit"]}
        if "judged" in c:
            props["judged"] = c["judged"]
        if verdict == "pass":
            cases.append(CaseVerdict(c["name"], "passed", properties=props))
        elif verdict == "fail":
            cases.append(CaseVerdict(c["name"], "failed", f"{c['name']}: {c['value']} {c['unit']} exceeds the limit {c['limit']} {c['unit']}", props))
        elif verdict.startswith("fail ("):
            cases.append(CaseVerdict(c["name"], "failed", f"{c['name']}: {verdict.removeprefix('fail ').strip('()')}", props))
        else:
            cases.append(CaseVerdict(c["name"], "skipped", verdict, props))
    if report.get("error"):
        cases.append(CaseVerdict("run", "error", f"the run failed: {report['error']}", {"ticks": report.get("ticks")}))
    run = report.get("run_verdict")
    if run:
        props = {"verdict": run["verdict"], "exit_code": run["exit_code"]}
        if run["verdict"] == "PASS":
            cases.append(CaseVerdict("run verdict", "passed", properties=props))
        elif run["verdict"] == "DEGRADED":  # the run went on: passed, what went wrong in its properties and output
            cases.append(CaseVerdict("run verdict", "passed", properties={**props, "reasons": "; ".join(run["reasons"])}))
        else:
            text = f"run verdict {run['verdict']}: " + "; ".join(run["reasons"])
            cases.append(CaseVerdict("run verdict", "failed" if run["verdict"] == "FAIL" else "error", text, props))
    return SuiteVerdict(
        f"timing-test.{report['scenario']['name']}",
        cases,
        {"mode": report.get("mode"), "ticks": report.get("ticks"), "batches": report.get("batches")},
        report.get("wall_time_s"),
    )


def experiment_suite(outcome: Any) -> SuiteVerdict:
    """One experiment's outcome (:class:`workbench.experiments.framework.RunOutcome`): a case per check
    of its report (its detail, which states the measured value against the limit, as a property and
    the failure text), an error case when it raised."""
    props = {"section": outcome.section, "status": outcome.status}
    if outcome.status == "error":
        trace = outcome.out_dir / "error.txt"
        detail = trace.read_text(encoding="utf-8") if trace.exists() else ""
        return SuiteVerdict(f"experiment.{outcome.name}", [CaseVerdict("run", "error", outcome.error, detail=detail)], props, outcome.runtime_s)
    cases = []
    for check in outcome.results().get("checks", []):
        detail = str(check.get("detail", ""))
        if check["passed"]:
            cases.append(CaseVerdict(check["name"], "passed", properties={"detail": detail}))
        else:
            cases.append(CaseVerdict(check["name"], "failed", f"{check['name']}: {detail}" if detail else check["name"], {"detail": detail}))
    return SuiteVerdict(f"experiment.{outcome.name}", cases, props, outcome.runtime_s)


def sweep_suite(name: str, rows: Sequence[Mapping[str, Any]], wall_s: float | None = None) -> SuiteVerdict:
    """A sweep's table (:class:`workbench.campaign.sweep.SweepResult` ``rows``): one case per run,
    named by its index and the settings that vary across the sweep, with those settings and the
    run's metrics as properties (settings every run shares go once, on the suite); a run that
    raised is an error with its text, a run never made (interrupted sweep) is skipped."""
    setting_cols = {k for row in rows for k in row if "." in k and "password" not in k}
    varied = sorted(k for k in setting_cols if len({repr(row.get(k)) for row in rows}) > 1)
    shared = {k: rows[0].get(k) for k in sorted(setting_cols - set(varied))} if rows else {}
    cases = []
    for row in rows:
        label = f"{row['index']:04d} " + (" ".join(f"{k}={row.get(k)}" for k in varied) or str(row["key"]))
        if row.get("label"):
            label += f" ({row['label']})"
        props = {k: v for k, v in row.items() if k != "error" and "password" not in k and (k not in setting_cols or k in varied)}
        time_s = row.get("run_s") if isinstance(row.get("run_s"), int | float) else None
        if row["status"] == "ok":
            cases.append(CaseVerdict(label, "passed", properties=props, time_s=time_s))
        elif row["status"] == "pending":
            cases.append(CaseVerdict(label, "skipped", "not run (the sweep stopped before it)", props))
        else:
            error = str(row.get("error") or "failed")
            cases.append(CaseVerdict(label, "error", error.splitlines()[0], props, time_s, detail=error))
    return SuiteVerdict(f"sweep.{name}", cases, {"runs": len(rows), **shared}, wall_s)
