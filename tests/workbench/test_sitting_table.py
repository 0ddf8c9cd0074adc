"""The sitting's table in docs/results/dsp-in-service.md is the command's output over its JSONs."""

from __future__ import annotations

from pathlib import Path

import pytest

from workbench.bench.sitting_table import main, sitting_table

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"
LABELS = {
    "3d7b469": "3d7b469 (before)",
    "b20a56c": "b20a56c (regressed)",
    "scipyform": "this tree, FFT forced to scipy.fft.rfft + copy",
    "fixed": "this tree (FFT form: binding)",
}


def test_the_published_table_is_the_commands_output() -> None:
    table = sitting_table(RESULTS / "dsp-in-service", LABELS)
    assert len(table.splitlines()) == 2 + 12  # header, rule, three rounds of four trees
    assert table in (RESULTS / "dsp-in-service.md").read_text(encoding="utf-8")


def test_an_empty_or_foreign_folder_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path)]) == 2
    assert "no bench JSON" in capsys.readouterr().err
    (tmp_path / "notes.json").write_text("{}", encoding="utf-8")
    assert main([str(tmp_path), "--label", "fixed=x"]) == 2
    assert "not TREE-ROUND.json" in capsys.readouterr().err
    assert main([str(tmp_path / "missing")]) == 2
