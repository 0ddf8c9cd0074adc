"""The results of a sweep: a journal (one JSON line per finished run, appended as runs finish) and the tidy table.

The journal ``runs.jsonl`` is the sweep's state: a resumed sweep reads it and
skips the keys whose last line says ``ok``. The tidy table (``results.parquet``
through pyarrow, and ``results.csv``) has one row per run of the spec, in the
spec's order, and one column per run fact, varied axis, setting and metric.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from protocol.settings import CommonSettings
from workbench.campaign.spec import SERVICES, VOLATILE, RunPoint

__all__ = ["Journal", "settings_columns", "to_columns", "write_table"]

META = ("index", "key", "rig_id", "mode", "status", "error", "worker", "run_s", "round_trip_s", "finished_utc")


class Journal:
    """Append-only ``runs.jsonl``: the last line of a key wins."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.rows: dict[str, dict[str, Any]] = {}
        if path.exists():
            for line in path.read_text(encoding="utf-8").splitlines():
                if not line.strip():
                    continue
                try:
                    row = json.loads(line)
                    self.rows[str(row["key"])] = row
                except (ValueError, KeyError):
                    continue  # a line cut short by a crash: that run is simply run again

    def finished(self) -> set[str]:
        return {k for k, r in self.rows.items() if r.get("status") == "ok"}

    def append(self, row: Mapping[str, Any]) -> None:
        self.rows[str(row["key"])] = dict(row)
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(_jsonable(row), allow_nan=True) + "\n")
            fh.flush()

    def clear(self) -> None:
        self.rows.clear()
        self.path.write_text("", encoding="utf-8")


def _jsonable(row: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in row.items():
        if isinstance(v, float) and not math.isfinite(v):
            out[k] = None if math.isnan(v) else ("inf" if v > 0 else "-inf")
        else:
            out[k] = v
    return out


def settings_columns(point: RunPoint) -> dict[str, Any]:
    """Every resolved setting of the run: ``common.X`` once when the three services agree, else ``SERVICE.X``."""
    out: dict[str, Any] = {}
    common = [f for f in CommonSettings.model_fields if f not in VOLATILE]
    for f in common:
        values = [point.settings[s][f] for s in SERVICES]
        if all(v == values[0] for v in values):
            out[f"common.{f}"] = values[0]
        else:
            out.update({f"{s}.{f}": point.settings[s][f] for s in SERVICES})
    for s in SERVICES:
        for f, v in point.settings[s].items():
            if f in VOLATILE or f in CommonSettings.model_fields:
                continue
            out[f"{s}.{f}"] = v
    return out


def _cell(value: Any) -> Any:
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    if value == "inf":
        return math.inf
    if value == "-inf":
        return -math.inf
    return value


def to_columns(rows: Sequence[Mapping[str, Any]]) -> dict[str, list[Any]]:
    """Rows to typed columns (bool, int, float or text; missing values None), in the META/axes/settings/metrics order of the rows."""
    names: list[str] = [m for m in META if any(m in r for r in rows)]
    for r in rows:
        for k in r:
            if k not in names:
                names.append(k)
    cols: dict[str, list[Any]] = {}
    for name in names:
        values = [_cell(r.get(name)) for r in rows]
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            cols[name] = values
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            cols[name] = values
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            cols[name] = [None if v is None else float(v) for v in values]
        else:
            cols[name] = [None if v is None else (v if isinstance(v, str) else json.dumps(v)) for v in values]
    return cols


def write_table(rows: Iterable[Mapping[str, Any]], out_dir: Path, stem: str = "results") -> tuple[Path, Path]:
    """``stem.parquet`` and ``stem.csv`` of ``rows``."""
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    rows = list(rows)
    table = pa.table(to_columns(rows)) if rows else pa.table({m: pa.array([], pa.string()) for m in META})
    parquet = out_dir / f"{stem}.parquet"
    csv = out_dir / f"{stem}.csv"
    pq.write_table(table, parquet)
    pacsv.write_csv(table, csv)
    return parquet, csv
