"""The plugin's reports of check results: a user's test file with the rig fixture
in cosim, run by pytest's own pytester with ``--junitxml`` (read back with
junitparser) and ``--html`` (pytest-html)."""

from __future__ import annotations

import re

import pytest

pytest_plugins = ["pytester"]

USER_TESTS = """
from workbench.checks import assert_check, check, signal, follows_reference, stays_within, rms_below, Signal, overshoot_below


def test_tracking_and_deflection(rig, checks):
    record = rig.run(duration_s=5.0)
    check(
        follows_reference(signal(record, "phi_ref2"), signal(record, "phi2"), tolerance=0.02, max_lag_s=0.2),
        stays_within(signal(record, "defl1_in"), -0.5, 0.5),
    )
    assert [r.passed for r in checks] == [True, True]


def test_a_check_that_fails():
    step = Signal.of([0.0, 1.0, 2.0, 3.0], [0.0, 1.5, 1.0, 1.0], "y")
    assert_check(overshoot_below(step, 10.0))


def test_a_check_over_nothing():
    assert_check(rms_below(Signal.of([], [], "nothing"), 1.0))
"""


def run(pytester: pytest.Pytester, *args: str) -> pytest.RunResult:
    pytester.makepyfile(test_user=USER_TESTS)
    return pytester.runpytest_subprocess("-p", "no:cacheprovider", *args)


def test_each_check_is_a_junit_property_and_a_figure_in_one_html_report(pytester: pytest.Pytester) -> None:
    xunit2 = pytest.importorskip("junitparser.xunit2")  # pytest writes junit_family xunit2
    pytest.importorskip("pytest_html")
    result = run(pytester, "--junitxml=out.xml", "--html=report.html", "--self-contained-html")
    result.assert_outcomes(passed=1, failed=2)
    result.stdout.re_match_lines([r".*AssertionError: overshoot_below\(y\) FAIL: overshoot 50.0 % against a limit of 10 %.*"])
    result.stdout.re_match_lines([r".*AssertionError: rms_below\(nothing\) INVALID: compared nothing: nothing has 0 samples.*"])

    xml = xunit2.JUnitXml.fromfile(str(pytester.path / "out.xml"))
    props = {case.name: {p.name: p.value for p in case.properties()} for suite in xml for case in suite}
    tracking = props["test_tracking_and_deflection"]
    assert set(tracking) == {"check:follows_reference(phi_ref2, phi2)", "check:stays_within(defl1_in)"}
    assert all(re.fullmatch(r"PASS measured=\S+ limit=\S+ unit=(rad|in)", v) for v in tracking.values())
    assert props["test_a_check_that_fails"] == {"check:overshoot_below(y)": "FAIL measured=50 limit=10 unit=%"}
    assert props["test_a_check_over_nothing"] == {"check:rms_below(nothing)": "INVALID measured=nan limit=1"}

    html = (pytester.path / "report.html").read_text(encoding="utf-8")
    assert len(re.findall(r"data:image/png;base64,iVBORw0KGgo", html)) == 4  # a PNG per check, embedded
    for name in ("follows_reference(phi_ref2, phi2) PASS", "stays_within(defl1_in) PASS", "overshoot_below(y) FAIL", "rms_below(nothing) INVALID"):
        assert name in html


def test_without_an_html_report_no_figure_is_drawn(pytester: pytest.Pytester) -> None:
    pytester.makeconftest(
        """
import workbench.checks.figure as figure

def boom(*args, **kwargs):
    raise AssertionError("a figure was drawn")

figure.draw = boom
"""
    )
    run(pytester).assert_outcomes(passed=1, failed=2)


def test_checks_work_without_pytest_html(pytester: pytest.Pytester) -> None:
    result = run(pytester, "-p", "no:html", "--junitxml=out.xml")
    result.assert_outcomes(passed=1, failed=2)
    assert "check:overshoot_below(y)" in (pytester.path / "out.xml").read_text(encoding="utf-8")
