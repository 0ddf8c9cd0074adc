"""Running a sweep: the spec's runs on the engine, journalled, tabled, resumable.

:func:`run_sweep` expands the spec (:mod:`workbench.campaign.spec`), skips the
points the journal of ``out_dir`` already has as ``ok`` (unless
``resume=False``), runs the others as one Dask task each through
:func:`workbench.campaign.modes.run_point`, appends each outcome to the journal
as it arrives (a failed run's row carries its error and no metrics) and
writes the tidy table of every point of the spec at the end, also when
interrupted.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from rich.console import Console

from workbench.campaign.engine import Engine, TaskOutcome
from workbench.campaign.modes import run_point
from workbench.campaign.spec import RunPoint, SweepSpec, expand
from workbench.campaign.table import Journal, settings_columns, write_table

__all__ = ["SweepResult", "run_sweep"]


@dataclass
class SweepResult:
    """What a sweep did."""

    out_dir: Path
    rows: list[dict[str, Any]]
    """One per point of the spec, in its order (points never run have status ``pending``)."""
    ran: int
    skipped: int
    failed: int
    wall_s: float
    parquet: Path
    csv: Path
    outcomes: list[TaskOutcome[dict[str, Any]]] = field(default_factory=list)

    @property
    def runs_per_hour(self) -> float:
        return 3600.0 * self.ran / self.wall_s if self.ran and self.wall_s > 0 else float("nan")


def point_row(point: RunPoint) -> dict[str, Any]:
    """The run's identity columns: meta, varied axes (not already a setting column), every setting."""
    settings = settings_columns(point)
    row: dict[str, Any] = {"index": point.index, "key": point.key, "rig_id": point.rig_id, "mode": point.mode, "status": "pending", "error": ""}
    for axis, value in point.axes.items():
        if axis not in settings and axis != "mode":
            row[axis] = value
    row.update(settings)
    return row


def run_sweep(
    spec: SweepSpec,
    out_dir: str | Path,
    engine: Engine,
    *,
    resume: bool = True,
    console: Console | None = None,
    show_progress: bool = True,
) -> SweepResult:
    """Run ``spec`` into ``out_dir`` (``runs.jsonl``, ``results.parquet``, ``results.csv``, ``spec.json``)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console = console or Console(stderr=True)
    points = expand(spec)
    (out / "spec.json").write_text(json.dumps(spec.model_dump(mode="json"), indent=2) + "\n", encoding="utf-8")
    journal = Journal(out / "runs.jsonl")
    if not resume:
        journal.clear()
    done = journal.finished()
    todo = [p for p in points if p.key not in done]
    skipped = len(points) - len(todo)
    console.print(
        f"sweep {spec.name!r}: {len(points)} run(s), {skipped} already finished, {len(todo)} to run on {engine.describe()}",
        highlight=False,
    )

    def record(outcome: TaskOutcome[dict[str, Any]]) -> None:
        point = todo[outcome.index]
        row = point_row(point)
        row.update(
            status="ok" if outcome.ok else "error",
            error=outcome.error,
            worker=outcome.worker,
            run_s=outcome.run_s,
            round_trip_s=outcome.round_trip_s,
            finished_utc=datetime.now(UTC).isoformat(timespec="seconds"),
        )
        if outcome.ok and outcome.value is not None:
            row.update(outcome.value)
        else:
            console.print(f"[red]run {point.key} ({point.axes}) failed:[/red] {outcome.error.splitlines()[0] if outcome.error else ''}", highlight=False)
        journal.append(row)

    started = time.perf_counter()
    outcomes: list[TaskOutcome[dict[str, Any]]] = []
    try:
        outcomes = engine.map(
            run_point, todo, keys=[f"run-{p.key}" for p in todo], description=f"sweep {spec.name}", on_done=record, console=console, show_progress=show_progress
        )
    finally:
        wall = time.perf_counter() - started
        rows = [journal.rows.get(p.key) or point_row(p) for p in points]
        # the journal's row of a point carries the metrics; its identity columns are the current ones
        rows = [{**r, **{k: v for k, v in point_row(p).items() if k not in ("status", "error")}} for r, p in zip(rows, points)]
        parquet, csv = write_table(rows, out)
    failed = sum(1 for o in outcomes if not o.ok)
    return SweepResult(out, rows, len(outcomes), skipped, failed, wall, parquet, csv, outcomes)
