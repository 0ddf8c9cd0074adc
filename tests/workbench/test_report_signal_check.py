"""An experiment's report takes a signal check as one of its checks, with its figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.checks import rms_below
from workbench.checks.signal import Signal
from workbench.experiments.report import Report


def test_a_signal_check_is_a_report_check_with_its_line_and_figure(tmp_path: Path) -> None:
    t = np.arange(0.0, 2.0, 0.005)
    sig = Signal(t, 0.1 * np.sin(2 * np.pi * 3.0 * t), "defl1_in", "in")
    rep = Report(tmp_path, "t")
    assert rep.signal_check(rms_below(sig, 0.08), figure="rms.png")
    assert not rep.signal_check(rms_below(sig, 0.05), "rms of defl1_in below 0.05 in")
    assert [c.passed for c in rep.checks] == [True, False]
    assert "0.0707" in rep.checks[0].detail and "0.05" in rep.checks[1].detail
    assert rep.checks[1].name == "rms of defl1_in below 0.05 in"
    assert (tmp_path / "rms.png").stat().st_size > 0 and rep.figures == ["rms.png"]


def test_a_check_over_nothing_fails_in_the_report(tmp_path: Path) -> None:
    rep = Report(tmp_path, "t")
    empty = Signal(np.zeros(0), np.zeros(0), "defl1_in", "in")
    assert not rep.signal_check(rms_below(empty, 1.0))
