"""An experiment's report lists its files relative to itself, never as a path of the machine that ran it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from workbench.experiments.report import Report


@pytest.mark.parametrize("given", ["absolute", "relative to the working directory", "relative to the report"])
def test_attachments_are_relative_to_the_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, given: str) -> None:
    monkeypatch.chdir(tmp_path)
    out = Path("docs") / "results" / "exp"  # --out as a user types it: relative
    (out / "records").mkdir(parents=True)
    target = out / "records" / "run.npz"
    target.write_bytes(b"")
    path = {"absolute": target.resolve(), "relative to the working directory": target, "relative to the report": Path("records") / "run.npz"}[given]
    report = Report(out, "title", name="exp")
    report.attach(path if given != "relative to the report" else out / path, "a run record")
    listed = report.attachments[0]["path"]
    assert listed == os.path.join("records", "run.npz")
    assert str(tmp_path) not in report.markdown() and str(tmp_path) not in str(report.as_json())


def test_a_file_beside_the_report_folder_is_listed_relative_too(tmp_path: Path) -> None:
    out = tmp_path / "results" / "exp"
    out.mkdir(parents=True)
    shared = tmp_path / "results" / "shared" / "truth.npz"  # e.g. a campaign's common file
    shared.parent.mkdir()
    shared.write_bytes(b"")
    report = Report(out, "title", name="exp")
    report.attach(shared, "the plant's truth")
    assert report.attachments[0]["path"] == "../shared/truth.npz"
    assert str(tmp_path) not in report.markdown() and str(tmp_path) not in str(report.as_json())
