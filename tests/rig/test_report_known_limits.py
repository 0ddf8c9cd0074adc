"""A goal out of the build's reach is a known limit: reported beside the checks, never a failed check."""

from __future__ import annotations

import json
from pathlib import Path

from workbench.experiments.report import Report


def test_known_limits_are_reported_and_do_not_count_as_checks(tmp_path: Path) -> None:
    rep = Report(tmp_path, "t")
    rep.check("what the build reached holds (≤ 5 s, reached 3.7 s)", True, "3.70 s")
    rep.known_limit("within 1 s after every step", "3.70 s", False)
    report, results = rep.write()
    text = report.read_text(encoding="utf-8")
    assert "## Known limits" in text and "| within 1 s after every step | 3.70 s | no |" in text
    assert "1 of 1 passed." in text
    assert text.index("## Known limits") < text.index("## Checks")
    data = json.loads(results.read_text(encoding="utf-8"))
    assert data["known_limits"] == [{"goal": "within 1 s after every step", "measured": "3.70 s", "met": False}]
    assert all(c["passed"] for c in data["checks"])


def test_a_report_without_known_limits_is_unchanged(tmp_path: Path) -> None:
    rep = Report(tmp_path, "t")
    rep.check("c", True)
    report, results = rep.write()
    assert "Known limits" not in report.read_text(encoding="utf-8")
    assert "known_limits" not in json.loads(results.read_text(encoding="utf-8"))
