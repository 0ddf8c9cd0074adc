"""The rig's warnings inside an experiment: counted in its report, not printed bare."""

from __future__ import annotations

import logging
import subprocess
import sys
from pathlib import Path

from workbench.experiments.report import Report
from workbench.service_warnings import WarningTally, add_remote, counted_warnings, kind_of

STALE = "stale: parameters stale at tick 9180 (2.00 s without a fresh estimate) (policy degrade)"


def test_kinds_are_the_word_before_the_first_colon_else_the_logger() -> None:
    assert kind_of(STALE, "controller.monitors") == "stale"
    assert kind_of("deadline: batch 246: compute 1023.2 ms over budget 100.0 ms", "dsp_service.core") == "deadline"
    assert kind_of("protocol violation: batch 3 arrived while the block was full; rejected", "dsp_service.board") == "dsp_service.board"
    assert kind_of("plant EMCY INPUT_SATURATED (0x5010), register 0x01", "plant_emulator.node") == "plant_emulator.node"


def test_the_rigs_warnings_are_counted_with_their_first_message() -> None:
    monitors, core = logging.getLogger("controller.monitors"), logging.getLogger("dsp_service.core")
    with counted_warnings() as tally:
        monitors.warning("%s (policy %s)", "stale: parameters stale at tick 9180 (2.00 s without a fresh estimate)", "degrade")
        monitors.warning("stale: parameters stale at tick 12000 (2.00 s without a fresh estimate) (policy degrade)")
        core.warning("deadline: %s", "batch 246: compute 1023.2 ms over budget 100.0 ms")
        core.info("deadline: an info line is not a warning")
        logging.getLogger("somebody.else").warning("stale: not the rig's")
    monitors.warning("stale: after the block: not counted")
    assert tally.as_dict() == {
        "deadline": {"count": 1, "first": "deadline: batch 246: compute 1023.2 ms over budget 100.0 ms"},
        "stale": {"count": 2, "first": STALE},
    }
    assert tally.line() == "deadline ×1, stale ×2" and tally.total == 3


def test_a_workers_counts_join_the_innermost_tally() -> None:
    worker = WarningTally()
    worker.add("stale", STALE, 4)
    with counted_warnings() as outer:
        with counted_warnings() as inner:
            add_remote(worker.as_dict())
    assert inner.as_dict() == {"stale": {"count": 4, "first": STALE}} and outer.total == 0
    add_remote(worker.as_dict())  # no tally open: dropped, no error


def test_nothing_reaches_stderr_inside_the_block() -> None:
    code = (
        "import logging\n"
        "from workbench.service_warnings import counted_warnings\n"
        "with counted_warnings() as t:\n"
        f"    logging.getLogger('controller.monitors').warning({STALE!r})\n"
        "print(t.line())\n"
        "logging.getLogger('controller.monitors').warning('outside')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert proc.stdout == "stale ×1\n"
    assert proc.stderr == "outside\n"  # outside the block Python's last resort prints as before


def test_the_report_lists_them(tmp_path: Path) -> None:
    report = Report(tmp_path, "t", name="t")
    assert "Warnings from the rig" not in report.markdown() and "service_warnings" not in report.as_json()
    report.service_warnings = {"stale": {"count": 31, "first": STALE}}
    assert f"| stale | 31 | {STALE} |" in report.markdown()
    assert report.as_json()["service_warnings"] == {"stale": {"count": 31, "first": STALE}}
