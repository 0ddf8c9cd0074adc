"""The README's figures table is built from the result files, not typed in:
a synthetic results folder gives the rows, counts and figures it holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from workbench.results_table import BEGIN, END, figures_table, main, replace_between_markers


def write(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))


def results_folder(root: Path) -> Path:
    experiments = [
        {"name": "battery", "section": "§4.2.3", "status": "ok", "runtime_s": 11.76, "checks_passed": 4, "checks_total": 4},
        {"name": "pi-spectrogram", "section": "§4.2.2", "status": "checks failed", "runtime_s": 47.1, "checks_passed": 8, "checks_total": 11},
        {"name": "vrm", "section": "App. C", "status": "ok", "runtime_s": 2.3, "checks_passed": 3, "checks_total": 3},
    ]
    write(root / "index.json", {"seed": 3, "mode": "cosim", "experiments": experiments})
    groups = {g: {"configs": {"b": {"velocity_pct": pct}}} for g, pct in (("slow", [52.5, 68.0]), ("fast", [41.1, 57.1]))}
    write(root / "battery" / "results.json", {"meta": {"finished_utc": "2026-12-02T09:47:44+00:00"}, "results": {"groups": groups}})
    write(
        root / "pi-spectrogram" / "results.json", {"meta": {"finished_utc": "2026-12-01T10:00:00+00:00"}, "results": {"lag": {"median_transition_lag_s": 7.1}}}
    )
    return root


def test_rows_counts_and_figures_come_from_the_files(tmp_path: Path) -> None:
    table = figures_table(results_folder(tmp_path))
    assert "(seed 3, cosim): 2 of 3 experiments pass every check" in table
    assert "| `battery`, §4.2.3 | 4/4 checks; fixed OATF tuned right leaves 41–68 % of the unfiltered RMS deflection velocity | 2026-12-02, 11.8 s |" in table
    assert "8/11 checks; identified first mode lags the true changes by 7.1 s (median) | 2026-12-01, 47.1 s |" in table
    assert "| `vrm`, App. C | 3/3 checks | —, 2.3 s |" in table  # no results.json: no date, no figure
    assert "compose" not in table and "bench" not in table  # no run.json, no bench report: no rows


def test_bench_rows_come_from_the_latest_report(tmp_path: Path) -> None:
    root = results_folder(tmp_path)
    machine = {"date": "2026-12-03T04:10:04+00:00", "cpu_model": "AMD EPYC", "cores": 2, "load_average_at_start": [0.5, 0.4, 0.3]}
    latency = {"p50_us": 31.4, "ratio": {"p50": 1.384}}
    items = {
        "dsp": {"measurements": {"identifier_step": latency}},
        "realtime": {"measurements": {"1000Hz deadline_misses": {"value": 0, "batches_sent": 299}, "1000Hz overruns per tick": {"ratio": 1.63}}},
    }
    write(root / "bench" / "z-older.json", {"machine": {**machine, "date": "2026-11-01T00:00:00+00:00"}, "items": {}})
    write(root / "bench" / "a-latest.json", {"machine": machine, "options": {"quick": False}, "items": items})
    table = figures_table(root)
    assert "`ralf-hil bench` (AMD EPYC, 2 cores, load 0.5 at the start)" in table
    assert "| bench `dsp` | identification step (N = 2048) p50 31 µs, 1.38× its numpy floor | 2026-12-03 |" in table
    assert "| bench `realtime` | 1000 Hz: 0 of 299 batches late; overruns 1.63× the sleep-only loop's | 2026-12-03 |" in table
    assert "200 Hz" not in table and "`can`" not in table  # measured nowhere: no row


def test_write_replaces_only_the_marked_part(tmp_path: Path) -> None:
    text = f"# title\n\n{BEGIN}\nold table\n{END}\n\n## next\n"
    assert replace_between_markers(text, "new table") == f"# title\n\n{BEGIN}\nnew table\n{END}\n\n## next\n"


def test_a_file_without_markers_is_refused_with_one_line(tmp_path: Path, capsys: Any) -> None:
    page = tmp_path / "page.md"
    page.write_text("# no markers\n")
    assert main(["--write", str(page)]) == 2
    assert capsys.readouterr().out.count("\n") == 1
    assert page.read_text() == "# no markers\n"
