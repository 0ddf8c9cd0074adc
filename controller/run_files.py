"""The controller's run record, timing record and their files.

The run record holds the law's row and the service's columns per tick
(deterministic: the co-simulation's are bit-identical run to run); the
timing record the wall-clock stamps. ``RALF_RUN_RECORD`` set: both stream
to disk in chunks; unset: nothing is kept (flat memory), unless the caller
reads the columns (``keep_record``: in-process runs).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from controller.fault_stage import FaultStage
from controller.hop_timing import HopTimer
from controller.record import ChunkedRecord, ColumnBuffer, RowCounter
from protocol.messages import TfSnapshot

Record = ChunkedRecord | ColumnBuffer | RowCounter
TIMING_COLUMNS: dict[str, type] = {"tick": np.int64, "sync_wall_s": np.float64, "tet_s": np.float64}


def make_records(run_record: str | None, keep_record: bool, columns: dict[str, type]) -> tuple[Record, Record]:
    """The run record and the timing record: streamed to ``run_record``, kept in memory, or only counted."""
    if run_record:
        return ChunkedRecord(run_record, columns), ChunkedRecord(run_record + ".timing", TIMING_COLUMNS)
    if keep_record:
        return ColumnBuffer(columns, capacity=4096), ColumnBuffer(TIMING_COLUMNS, capacity=4096)
    return RowCounter(columns), RowCounter(TIMING_COLUMNS)


def save_run(
    path: str,
    records: tuple[Record, Record],
    settings: dict[str, Any],
    metadata: dict[str, Any],
    faults: FaultStage | None,
    hops: HopTimer | None,
    snapshots: list[TfSnapshot],
) -> None:
    """Write the run record (deterministic columns), the timing record, the
    real-time per-hop stamps (``hops``, None in lockstep) and the TF downloads."""
    record, timing_record = records
    if isinstance(record, RowCounter) or isinstance(timing_record, RowCounter):
        raise ValueError("this run keeps no record: set RALF_RUN_RECORD to save one")
    if faults is not None:
        metadata["faults"] = {
            "scenario": faults.engine.scenario.model_dump(),
            "counters": faults.as_counters(),
            "events": [dataclasses.asdict(e) for e in faults.engine.events[:10000]],
        }
    record.save(path, settings, metadata)
    timing_record.save(path + ".timing", None, {"note": "wall-clock timing; differs run to run"})
    if hops is not None and hops.n:
        save_hops(hops, path + ".hops.npz")
    if snapshots:
        freqs = np.asarray(snapshots[-1].freqs_hz)
        same = [s for s in snapshots if len(s.freqs_hz) == freqs.size]
        columns: dict[str, np.ndarray] = {"sim_time_s": np.array([s.sim_time_s for s in same])}
        for name in ("H11", "H12", "H21", "H22", "Htot"):
            columns[f"{name}_mag"] = np.array([s.estimates[name].magnitude for s in same])
        np.savez_compressed(path + ".tf.npz", freqs_hz=freqs, **columns)  # type: ignore[arg-type]


def save_hops(hops: HopTimer, path: str) -> None:
    """Real time: the tick path's raw per-hop stamps (wall clock, differs run to
    run; beside the timing record, never in the run record): per tick run, the
    last ``capacity`` of them in the order of the timing record's last rows, the
    wake-up lateness (ns, -1 not measured) and the stopwatch ns
    (``time.perf_counter_ns``: CLOCK_MONOTONIC, what ``perf record -k
    CLOCK_MONOTONIC`` stamps) of the SYNC sent, the TPDO1 in and the tick
    done, so an overrun can be set against a system trace."""
    m = min(hops.n, hops.capacity)
    raw = np.frombuffer(hops.raw, dtype=np.int64)[: 4 * m].reshape(m, 4)
    if hops.n > hops.capacity:  # the ring wrapped: its oldest row is the next to be written
        raw = np.roll(raw, -(hops.n % hops.capacity), axis=0)
    np.savez(path, wakeup_ns=raw[:, 0], sync_ns=raw[:, 1], tpdo_ns=raw[:, 2], done_ns=raw[:, 3])
