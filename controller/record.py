"""The run record: per-tick columns in a compressed ``.npz`` plus a JSON sidecar.

A record is any set of equal-length 1-D arrays (time, set-points, commands,
raw counts, engineering values, the active OATF parameters, ...) and two
JSON-able dictionaries: the run's configuration and free-form metadata.
``save_record("runs/x", ...)`` writes ``runs/x.npz`` (``numpy.savez_compressed``,
loaded without pickle) and ``runs/x.json`` (format tag, version, column
names, dtypes, length, configuration, metadata).  Both files are written to
a temporary name and renamed, so a reader never sees half a record.

:class:`ColumnBuffer` collects one tick at a time for the loop: every column
is a preallocated array that doubles when full, so an append is a few scalar
stores and the whole run is never re-copied more than ``log2(n)`` times.
This module is the only one of the controller's core that does I/O.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import zipfile
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import numpy.typing as npt

__all__ = ["RECORD_FORMAT", "RECORD_VERSION", "ChunkedRecord", "ColumnBuffer", "RowCounter", "RunRecord", "load_record", "save_record", "to_jsonable"]

RECORD_FORMAT = "ralf-hil-run-record"
RECORD_VERSION = 1
ROW_BLOCK = 128
"""Rows :meth:`ColumnBuffer.append_row` keeps before storing them in the columns at once.
The store runs in the loop's tick: 1024 rows of 22 columns took 1.1 ms (an
overrun at 1 kHz once a second, seen in the acceptance runs' timing
records); 128 take ~0.14 ms."""
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]*$")


@dataclass
class RunRecord:
    """A loaded run: columns by name, configuration and metadata as stored."""

    columns: dict[str, npt.NDArray[Any]]
    config: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return 0 if not self.columns else int(next(iter(self.columns.values())).shape[0])

    def __getitem__(self, name: str) -> npt.NDArray[Any]:
        return self.columns[name]


def _paths(path: str | Path) -> tuple[Path, Path]:
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".npz", ".json") else p
    return stem.with_name(stem.name + ".npz"), stem.with_name(stem.name + ".json")


def _validate_columns(columns: Mapping[str, npt.ArrayLike]) -> dict[str, npt.NDArray[Any]]:
    out: dict[str, npt.NDArray[Any]] = {}
    length: int | None = None
    for name, values in columns.items():
        if not isinstance(name, str) or not _NAME.match(name):
            raise ValueError(f"column name {name!r} must match {_NAME.pattern}")
        arr = np.asarray(values)
        if arr.ndim != 1:
            raise ValueError(f"column {name!r} must be 1-D, got shape {arr.shape}")
        if arr.dtype == object:
            raise ValueError(f"column {name!r} has dtype object; use numeric or boolean arrays")
        if length is None:
            length = arr.shape[0]
        elif arr.shape[0] != length:
            raise ValueError(f"column {name!r} has {arr.shape[0]} rows, expected {length}")
        out[name] = arr
    return out


def to_jsonable(value: Any) -> Any:
    """Turn configuration objects (pydantic models, dataclasses, numpy values, paths) into JSON types.

    Non-finite floats become the strings ``"nan"``, ``"inf"``, ``"-inf"`` so the file stays strict JSON.
    """
    if hasattr(value, "model_dump"):
        return to_jsonable(value.model_dump(mode="python"))
    if hasattr(value, "__dataclass_fields__"):
        return {k: to_jsonable(getattr(value, k)) for k in value.__dataclass_fields__}
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return [to_jsonable(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else ("nan" if math.isnan(value) else ("inf" if value > 0 else "-inf"))
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, Iterable):
        return [to_jsonable(v) for v in value]
    return str(value)


def save_record(
    path: str | Path,
    columns: Mapping[str, npt.ArrayLike],
    config: Any = None,
    metadata: Mapping[str, Any] | None = None,
) -> tuple[Path, Path]:
    """Write ``<path>.npz`` and ``<path>.json`` (a ``.npz``/``.json`` suffix on ``path`` is ignored).

    ``config`` may be a pydantic model, a dataclass or a dict; it is stored as JSON.
    Returns the two paths written.
    """
    cols = _validate_columns(columns)
    npz_path, json_path = _paths(path)
    npz_path.parent.mkdir(parents=True, exist_ok=True)
    tmp_npz = npz_path.with_name(npz_path.name + ".tmp.npz")
    with open(tmp_npz, "wb") as fh:
        # allow_pickle spelled out (numpy's default): a column can then not be taken for the flag
        np.savez_compressed(fh, allow_pickle=True, **cols)
    n = len(next(iter(cols.values()))) if cols else 0
    return _commit(tmp_npz, npz_path, json_path, n, {name: str(arr.dtype) for name, arr in cols.items()}, config, metadata)


def _commit(
    tmp_npz: Path, npz_path: Path, json_path: Path, n: int, dtypes: dict[str, str], config: Any, metadata: Mapping[str, Any] | None
) -> tuple[Path, Path]:
    """Write the sidecar and rename both files into place."""
    sidecar = {
        "format": RECORD_FORMAT,
        "version": RECORD_VERSION,
        "n_samples": n,
        "columns": dtypes,
        "config": to_jsonable(config) if config is not None else {},
        "metadata": to_jsonable(dict(metadata or {})),
    }
    tmp_json = json_path.with_name(json_path.name + ".tmp")
    tmp_json.write_text(json.dumps(sidecar, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp_npz, npz_path)
    os.replace(tmp_json, json_path)
    return npz_path, json_path


def load_record(path: str | Path) -> RunRecord:
    """Read a record written by :func:`save_record` (either file's path, or the common stem)."""
    npz_path, json_path = _paths(path)
    sidecar = json.loads(json_path.read_text(encoding="utf-8"))
    if sidecar.get("format") != RECORD_FORMAT:
        raise ValueError(f"{json_path} is not a {RECORD_FORMAT} sidecar")
    if int(sidecar.get("version", -1)) > RECORD_VERSION:
        raise ValueError(f"{json_path} has record version {sidecar['version']}, newer than {RECORD_VERSION}")
    with np.load(npz_path, allow_pickle=False) as data:
        order = list(sidecar.get("columns", {})) or list(data.files)
        columns = {name: data[name] for name in order}
    return RunRecord(columns=columns, config=sidecar.get("config", {}), metadata=sidecar.get("metadata", {}))


class ColumnBuffer:
    """Append-one-tick-at-a-time columnar storage: preallocated, grows by doubling.

    Columns are declared up front (``names`` or ``{name: dtype}``); every
    :meth:`append` must give every column (a missing or unknown name is an
    error, so a record never has ragged columns).
    """

    def __init__(self, columns: Iterable[str] | Mapping[str, npt.DTypeLike], capacity: int = 1024) -> None:
        spec = dict(columns) if isinstance(columns, Mapping) else {name: np.float64 for name in columns}
        _validate_columns({name: np.zeros(0, dtype=dt) for name, dt in spec.items()})
        if not spec:
            raise ValueError("a ColumnBuffer needs at least one column")
        self._capacity = max(1, int(capacity))
        self._data: dict[str, npt.NDArray[Any]] = {n: np.zeros(self._capacity, dtype=dt) for n, dt in spec.items()}
        self._n = 0
        self._rows: list[Sequence[Any]] = []
        """Rows given by :meth:`append_row`, not yet stored in the columns."""
        self._width = len(self._data)

    @property
    def names(self) -> list[str]:
        return list(self._data)

    @property
    def capacity(self) -> int:
        return self._capacity

    def __len__(self) -> int:
        return self._n + len(self._rows)

    def append_row(self, values: Sequence[Any]) -> None:
        """Store one tick given as one scalar per column in the order of
        :attr:`names` (the loop's per-tick form: no mapping built or matched).
        The values are stored as :meth:`append` stores them; the sequence is
        kept until then, so it must not be changed afterwards."""
        if len(values) != self._width:
            raise ValueError(f"append_row needs {self._width} values (one per column), got {len(values)}")
        rows = self._rows
        rows.append(values)
        if len(rows) >= ROW_BLOCK:
            self._settle()

    def _settle(self) -> None:
        """Store the rows kept by :meth:`append_row` in the columns (one slice
        assignment per column: each value converted to the column's dtype as a
        scalar store would)."""
        rows = self._rows
        if not rows:
            return
        n = len(rows)
        while self._n + n > self._capacity:
            self._grow()
        i = self._n
        for arr, values in zip(self._data.values(), zip(*rows, strict=True), strict=True):
            arr[i : i + n] = values
        self._n = i + n
        self._rows = []

    def append(self, row: Mapping[str, Any] | None = None, /, **values: Any) -> None:
        """Store one tick: a mapping and/or keywords giving one scalar per column."""
        if self._rows:
            self._settle()
        vals = {**row, **values} if row is not None else values
        if vals.keys() != self._data.keys():
            missing = sorted(set(self._data) - set(vals))
            unknown = sorted(set(vals) - set(self._data))
            raise KeyError(f"append needs exactly the buffer's columns; missing {missing}, unknown {unknown}")
        if self._n == self._capacity:
            self._grow()
        i = self._n
        for name, v in vals.items():
            self._data[name][i] = v
        self._n = i + 1

    def _grow(self) -> None:
        self._capacity *= 2
        for name, arr in self._data.items():
            new = np.zeros(self._capacity, dtype=arr.dtype)
            new[: self._n] = arr[: self._n]
            self._data[name] = new

    def column(self, name: str) -> npt.NDArray[Any]:
        """A read-only view of the filled part of one column."""
        self._settle()
        view = self._data[name][: self._n]
        view.flags.writeable = False
        return view

    def to_columns(self) -> dict[str, npt.NDArray[Any]]:
        """Copies of the filled part of every column (safe to keep after further appends)."""
        self._settle()
        return {name: arr[: self._n].copy() for name, arr in self._data.items()}

    def clear(self) -> None:
        """Forget the rows; keep the allocated capacity."""
        self._n = 0
        self._rows = []

    def save(self, path: str | Path, config: Any = None, metadata: Mapping[str, Any] | None = None) -> tuple[Path, Path]:
        """:func:`save_record` of the filled rows."""
        return save_record(path, self.to_columns(), config, metadata)


class RowCounter:
    """The record sink of a run that keeps no record (``RALF_RUN_RECORD`` unset):
    it counts rows and stores nothing, so memory stays flat however long the
    run (a :class:`ColumnBuffer` would grow by ~3 MB a minute at 200 Hz)."""

    def __init__(self, columns: Iterable[str] | Mapping[str, npt.DTypeLike]) -> None:
        self._names = list(dict(columns) if isinstance(columns, Mapping) else columns)
        self._n = 0

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def __len__(self) -> int:
        return self._n

    def append(self, row: Mapping[str, Any] | None = None, /, **values: Any) -> None:
        self._n += 1

    def append_row(self, values: Sequence[Any]) -> None:
        self._n += 1


class ChunkedRecord:
    """A run record streamed to disk while it is taken: rows collect in a
    :class:`ColumnBuffer` of ``chunk_rows``; each full chunk is appended to one
    raw file per column in ``<path>.parts/``. :meth:`save` writes the usual
    ``<path>.npz`` (each column streamed into its zip member, never loaded
    whole) and ``<path>.json``, then removes the parts. Memory stays at two
    chunks whatever the run's length; the files are what :func:`load_record`
    reads, byte for byte the same columns as :func:`save_record` would write.

    A full chunk is not written in the row that fills it: rows go on into a
    second buffer, and each of the next rows writes one column of the full
    chunk (in column order; the chunk is done after as many rows as there are
    columns, far fewer than a chunk's rows). Written at once, a 4096-row chunk
    of the controller's record and of its timing record cost the 1 kHz loop's
    tick ~1 ms, an overrun every 4.1 s (docs/timing.md)."""

    def __init__(self, path: str | Path, columns: Iterable[str] | Mapping[str, npt.DTypeLike], chunk_rows: int = 4096) -> None:
        self._buffer = ColumnBuffer(columns, capacity=chunk_rows)
        self._spare = ColumnBuffer(columns, capacity=chunk_rows)
        """The full chunk being written (its columns in ``_pending``), else an empty buffer for the next."""
        self._pending: list[tuple[BinaryIO, npt.NDArray[Any]]] = []
        self._pending_rows = 0
        self._chunk = max(1, int(chunk_rows))
        npz_path, _ = _paths(path)
        self._path = path
        self._parts = npz_path.with_name(npz_path.name[: -len(".npz")] + ".parts")
        self._parts.mkdir(parents=True, exist_ok=True)
        self._dtypes = {name: self._buffer.column(name).dtype for name in self._buffer.names}
        self._files: dict[str, BinaryIO] = {name: open(self._parts / f"{name}.bin", "wb") for name in self._buffer.names}  # noqa: SIM115 (closed in save/close)
        self._flushed = 0
        self.chunks_written = 0
        self._saved: tuple[Path, Path] | None = None
        """The files :meth:`save` wrote (the parts are gone then)."""

    @property
    def names(self) -> list[str]:
        return self._buffer.names

    def __len__(self) -> int:
        return self._flushed + self._pending_rows + len(self._buffer)

    def append(self, row: Mapping[str, Any] | None = None, /, **values: Any) -> None:
        self._buffer.append(row, **values)
        self._after_row()

    def append_row(self, values: Sequence[Any]) -> None:
        """:meth:`ColumnBuffer.append_row` into the current chunk."""
        self._buffer.append_row(values)
        self._after_row()

    def _after_row(self) -> None:
        if self._pending:
            self._write_pending(1)
        if len(self._buffer) >= self._chunk:
            self._rotate()

    def _rotate(self) -> None:
        """The full chunk's columns queued for the next rows to write; rows go
        on into the spare buffer."""
        self._write_pending(len(self._pending))  # the chunk before (done long since with chunks of thousands of rows)
        full = self._buffer
        self._buffer, self._spare = self._spare, full
        self._pending_rows = len(full)
        self._pending = [(self._files[name], full.column(name)) for name in full.names]

    def _write_pending(self, columns: int) -> None:
        """Write up to ``columns`` of the full chunk's columns; the chunk done, its buffer is the spare."""
        pending = self._pending
        for _ in range(min(columns, len(pending))):
            fh, column = pending.pop(0)
            fh.write(column.tobytes())
            fh.flush()
        if not pending and self._pending_rows:
            self._flushed += self._pending_rows
            self._pending_rows = 0
            self._spare.clear()
            self.chunks_written += 1

    def flush(self) -> None:
        """Append every buffered row to the parts files."""
        self._write_pending(len(self._pending))
        n = len(self._buffer)
        if not n:
            return
        for name, fh in self._files.items():
            fh.write(self._buffer.column(name).tobytes())
            fh.flush()
        self._flushed += n
        self._buffer.clear()
        self.chunks_written += 1

    def to_columns(self) -> dict[str, npt.NDArray[Any]]:
        """The whole record read back (for tests and small runs)."""
        if self._saved is not None:
            return load_record(self._saved[0]).columns
        self.flush()
        return {name: np.fromfile(self._parts / f"{name}.bin", dtype=dt) for name, dt in self._dtypes.items()}

    def save(self, path: str | Path | None = None, config: Any = None, metadata: Mapping[str, Any] | None = None) -> tuple[Path, Path]:
        """Write ``<path>.npz`` and ``<path>.json`` from the parts (streamed), then
        remove them. Saved once already: the same path is left as written, another
        gets a copy of the columns with this sidecar."""
        if self._saved is not None:
            return self._saved_again(path if path is not None else self._path, config, metadata)
        self.flush()
        for fh in self._files.values():
            fh.close()
        npz_path, json_path = _paths(path if path is not None else self._path)
        npz_path.parent.mkdir(parents=True, exist_ok=True)
        tmp_npz = npz_path.with_name(npz_path.name + ".tmp.npz")
        n = self._flushed
        with zipfile.ZipFile(tmp_npz, "w", compression=zipfile.ZIP_DEFLATED, allowZip64=True) as zf:
            for name, dt in self._dtypes.items():
                with zf.open(f"{name}.npy", "w", force_zip64=True) as member, open(self._parts / f"{name}.bin", "rb") as raw:
                    np.lib.format.write_array_header_1_0(member, {"descr": np.lib.format.dtype_to_descr(dt), "fortran_order": False, "shape": (n,)})
                    shutil.copyfileobj(raw, member, 1 << 20)
        out = _commit(tmp_npz, npz_path, json_path, n, {name: str(dt) for name, dt in self._dtypes.items()}, config, metadata)
        shutil.rmtree(self._parts, ignore_errors=True)
        self._saved = out
        return out

    def _saved_again(self, path: str | Path, config: Any, metadata: Mapping[str, Any] | None) -> tuple[Path, Path]:
        assert self._saved is not None
        npz_path, json_path = _paths(path)
        if npz_path.resolve() == self._saved[0].resolve():
            return self._saved
        npz_path.parent.mkdir(parents=True, exist_ok=True)
        tmp_npz = npz_path.with_name(npz_path.name + ".tmp.npz")
        shutil.copyfile(self._saved[0], tmp_npz)
        return _commit(tmp_npz, npz_path, json_path, self._flushed, {name: str(dt) for name, dt in self._dtypes.items()}, config, metadata)

    def close(self) -> None:
        """Drop the parts without saving."""
        self._pending = []
        for fh in self._files.values():
            fh.close()
        shutil.rmtree(self._parts, ignore_errors=True)
