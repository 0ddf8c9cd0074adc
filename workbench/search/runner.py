"""One candidate on the rig: a :class:`workbench.hil.HilRig` run and its property's results."""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from workbench.checks.result import CheckResult
from workbench.hil import HilRig, RunRecord
from workbench.search.properties import Properties
from workbench.search.strategies import Candidate

SearchClock = Literal["cosim", "lockstep"]


@dataclass(frozen=True)
class Outcome:
    """What one run of a candidate showed."""

    results: tuple[CheckResult, ...]
    summary: str
    """The run's :meth:`RunRecord.summary` line."""
    wall_s: float

    @property
    def violated(self) -> bool:
        return any(not r.passed for r in self.results)

    def lines(self) -> list[str]:
        return [r.line() for r in self.results]

    def same_as(self, other: Outcome) -> bool:
        """The same verdicts and measured values (a deterministic run repeats them exactly)."""
        return self.lines() == other.lines()


def run_rig(candidate: Candidate, clock: SearchClock = "cosim", workdir: Path | None = None) -> RunRecord:
    """Run ``candidate`` on a fresh rig (its MCAP recording, cosim, goes to ``workdir``)."""
    s = candidate.rig_settings()
    rig = HilRig(
        clock=clock,
        controller=s["controller"],
        plant_settings=s["plant"],
        dsp_settings=s["dsp"],
        common=s["common"],
        faults=candidate.faults(),
        workdir=workdir,
    )
    try:
        return rig.run(candidate.duration_s)
    finally:
        rig.close()


def evaluate(candidate: Candidate, properties: Properties, clock: SearchClock = "cosim", keep: Path | None = None) -> tuple[Outcome, RunRecord]:
    """Run ``candidate`` and judge it; its files go to ``keep`` (else a folder removed at once)."""
    workdir = keep or Path(tempfile.mkdtemp(prefix="ralf-search-run-"))
    workdir.mkdir(parents=True, exist_ok=True)
    try:
        record = run_rig(candidate, clock, workdir)
        outcome = Outcome(tuple(properties.judge(record)), record.summary(), record.wall_time_s)
    finally:
        if keep is None:
            shutil.rmtree(workdir, ignore_errors=True)
    return outcome, record


def rig_runner(properties: Properties, clock: SearchClock = "cosim") -> Any:
    """The search's default runner: candidate -> :class:`Outcome`."""
    return lambda candidate: evaluate(candidate, properties, clock)[0]
