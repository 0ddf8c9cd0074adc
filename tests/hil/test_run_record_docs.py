"""docs/pytest-plugin.md lists every field of a ``RunRecord`` and every counter a test can
assert on, generated from the code (workbench/run_record_docs.py): the page holds exactly the
generated text, every listed item has a meaning, and a run's counters are all listed."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from workbench.hil import HilRig, RunRecord
from workbench.run_record_docs import BEGIN, END, PAGE, counter_names, is_listed, run_record_tables

ROOT = Path(__file__).resolve().parents[2]


def test_the_page_holds_the_generated_tables() -> None:
    section = (ROOT / PAGE).read_text().split(BEGIN, 1)[1].split(END, 1)[0]
    assert section == run_record_tables(), "regenerate it: python -m workbench.run_record_docs"


def test_every_field_and_counter_has_a_meaning() -> None:
    rows = [row for row in run_record_tables().splitlines() if row.startswith("| `")]
    assert len(rows) > len(dataclasses.fields(RunRecord)) + len(counter_names())
    assert [row for row in rows if row.rstrip().endswith("|  |")] == []  # a field or counter without its docstring


def test_a_runs_counters_are_all_listed(tmp_path: Path) -> None:
    rig = HilRig(clock="cosim", workdir=tmp_path)
    try:
        record = rig.run(duration_s=1.0)
    finally:
        rig.close()
    assert record.counters and [name for name in record.counters if not is_listed(name)] == []
    assert set(counter_names()) <= set(record.counters)
    assert is_listed("in_command_dropped_rate") and is_listed("fault_dropped_sync") and not is_listed("no_such_counter")
