"""A recording as an ASAM MDF 4.1 file (``.mf4``), for CANape, INCA, the
asammdf GUI and every other MDF reader: ``ralf-hil export --mf4 OUT.mf4
RUN.mcap``, or ``ralf-hil up --record run.mf4``.

Every numeric measurement of the recording becomes a channel with its unit,
one channel group per topic (and per rate: a batch's samples, a TF grid size),
as :mod:`workbench.recording.mf4_channels` tabulates. The time axis of every
group is the rig's *simulated* time in seconds; the file's start time is the
wall-clock time of simulated time 0 (so a reader adding the two gets the
recording's log time of a co-simulation, and about the tap's receive time of
a real-time run). The CAN frames go in as ASAM bus logging: one
``CAN_DataFrame`` channel group in python-can's own record layout
(``can.io.mf4.STD_DTYPE``, what ``can.MF4Writer`` writes), marked as a CAN bus
event group, with ``protocol/ralf.dbc`` attached so a reader decodes the
signals itself. Written with asammdf.
"""

from __future__ import annotations

import datetime as dt
import hashlib
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

import can.io.mf4  # before asammdf: imported after it, python-can's MF4 support finds asammdf half-initialised and stays off
import numpy as np
from asammdf import MDF, Signal
from asammdf.blocks.v4_blocks import SourceInformation
from asammdf.blocks.v4_constants import BUS_TYPE_CAN, SOURCE_BUS

from workbench.recording import mf4_channels as table
from workbench.recording import schemas
from workbench.recording.reader import Recording

MDF_VERSION = "4.10"
SUFFIX = ".mf4"
CAN_BUS_CHANNEL = 1
"""The bus channel every frame is logged on (the rig has one CAN bus)."""


@dataclass
class ExportSummary:
    """What went into the file: groups, channels, samples, CAN frames, and the topics left out (why)."""

    path: str
    groups: int = 0
    channels: int = 0
    samples: int = 0
    can_frames: int = 0
    left_out: dict[str, str] = field(default_factory=dict)

    def line(self) -> str:
        out = f"{self.path}: {self.channels} channels in {self.groups} channel groups, {self.samples} samples, {self.can_frames} CAN frames"
        if self.left_out:
            out += "; left out: " + ", ".join(f"{t} ({why})" for t, why in self.left_out.items())
        return out


def time_zero(rec: Recording) -> float:
    """The wall-clock time (Unix s) of simulated time 0: log time minus simulated time of the
    first CAN frame that has one (else of the first message that has one; else the run's start)."""
    for wanted in (schemas.CAN_TOPIC, None):
        for m in rec.messages:
            if (wanted is None or m.topic == wanted) and isinstance(m.data.get("sim_time_s"), int | float):
                return m.log_time_ns / 1e9 - float(m.data["sim_time_s"])
    started = rec.metadata.get("ralf.run", {}).get("started_utc")
    if started:
        return dt.datetime.fromisoformat(started.replace("Z", "+00:00")).timestamp()
    return rec.messages[0].log_time_ns / 1e9 if rec.messages else 0.0


def export(rec: Recording, out: str | Path) -> ExportSummary:
    """Write ``rec`` to ``out`` (MDF 4.10); raises ``ValueError`` for data the table cannot place."""
    out = Path(out)
    t0 = time_zero(rec)
    units = table.dbc_units()
    summary = ExportSummary(str(out))
    mdf: Any = MDF(version=MDF_VERSION)
    mdf.header.start_time = dt.datetime.fromtimestamp(t0, tz=dt.UTC)
    mdf.header.comment = header_comment(rec)
    try:
        for topic, (schema, rows, log_ns) in table.topic_rows(rec.messages).items():
            times = table.sim_times(rows, log_ns, t0)
            if topic == schemas.CAN_TOPIC:
                summary.can_frames = append_can(mdf, rows, times)
                summary.groups += 1
                continue
            groups = table.message_groups(topic, schema, rows, times, units)
            if not groups:
                summary.left_out[topic] = table.left_out_because(schema) or "no numbers"
            for group in groups:
                if not group.columns:
                    summary.left_out[f"{topic} ({group.name})"] = "no numbers"
                    continue
                append_group(mdf, group)
                summary.groups += 1
                summary.channels += len(group.columns)
                summary.samples += len(group.time_s) * len(group.columns)
        out.parent.mkdir(parents=True, exist_ok=True)
        mdf.save(out, overwrite=True)
    finally:
        mdf.close()
    return summary


def header_comment(rec: Recording) -> str:
    run = rec.metadata.get("ralf.run", {})
    return (
        f"ralf-hil recording of rig {rec.rig_id!r} exported from {rec.path.name}"
        f" (clock {run.get('clock', 'realtime or lockstep')}, started {run.get('started_utc', 'unknown')}). "
        "Time axis of every channel group: the rig's simulated time in s; the file's start time is the wall-clock time of simulated time 0. "
        "Channels: <topic below ralf/<rig>/ with '.'>.<field> (docs/recording.md, MF4); CAN frames: ASAM bus logging group CAN_DataFrame."
    )


def append_group(mdf: Any, group: table.Group) -> None:
    """One channel group: a Signal per column (array columns as one structured channel)."""
    signals = []
    for c in group.columns:
        samples: Any = c.values
        if c.values.ndim == 2:
            samples = np.rec.fromarrays([c.values], dtype=np.dtype([(c.name, c.values.dtype, (c.values.shape[1],))]))
        conversion: dict[str, object] | None = None
        if c.states:
            conversion = {k: v for i, s in enumerate(c.states) for k, v in ((f"val_{i}", i), (f"text_{i}", s))}
        signals.append(
            Signal(
                samples,
                group.time_s,
                name=c.name,
                unit=c.unit,
                conversion=conversion,
                invalidation_bits=c.invalid,
                comment=f"{group.topic}: {c.name.removeprefix(group.name + '.')}",
            )
        )
    comment = f"{group.topic}; time: simulated time (s)" + (f"; {group.note}" if group.note else "")
    mdf.append(signals, comment=comment)


def append_can(mdf: Any, rows: list[dict[str, Any]], times: list[float]) -> int:
    """The CAN frames as one ASAM bus logging group ``CAN_DataFrame`` (python-can's layout;
    Dir: Tx for controller -> plant, Rx otherwise, as ``replay --export-can`` marks them)."""
    frames = np.zeros(len(rows), dtype=can.io.mf4.STD_DTYPE)
    lengths = np.array([len(r["data"]) for r in rows], dtype=np.int64)
    if lengths.size and lengths.max() > 8:
        i = int(np.argmax(lengths))
        raise ValueError(f"CAN frame {i}: {lengths[i]} data bytes (classic CAN holds 8)")
    payload = np.zeros((len(rows), 8), dtype=np.uint8)
    for i, r in enumerate(rows):
        payload[i, : lengths[i]] = r["data"]
    frames["CAN_DataFrame.BusChannel"] = CAN_BUS_CHANNEL
    frames["CAN_DataFrame.ID"] = [int(r["arbitration_id"]) for r in rows]
    frames["CAN_DataFrame.IDE"] = [bool(r["is_extended_id"]) for r in rows]
    frames["CAN_DataFrame.DLC"] = [int(r.get("dlc", n)) for r, n in zip(rows, lengths)]
    frames["CAN_DataFrame.DataLength"] = lengths
    frames["CAN_DataFrame.DataBytes"][:, :8] = payload
    frames["CAN_DataFrame.Dir"] = [r.get("direction") == schemas.TO_PLANT for r in rows]
    dbc = files("protocol").joinpath("ralf.dbc").read_bytes()
    mdf.append(
        Signal(
            name="CAN_DataFrame",
            samples=frames,
            timestamps=np.asarray(times, dtype=np.float64),
            attachment=(dbc, Path("ralf.dbc"), hashlib.md5(dbc).digest()),
            source=SourceInformation(source_type=SOURCE_BUS, bus_type=BUS_TYPE_CAN),
        ),
        comment=f"{schemas.CAN_TOPIC}: every CAN frame (ASAM bus logging); time: simulated time (s) of the frame's SYNC period",
    )
    return len(rows)


def export_file(recording: str | Path, out: str | Path) -> ExportSummary:
    """Read ``recording`` (MCAP) and write ``out`` (MF4)."""
    rec = Recording.load(recording)
    if not rec.messages:
        raise ValueError(f"{rec.cut or 'the recording holds no message'}: nothing to export")
    summary = export(rec, out)
    if rec.cut:
        summary.left_out["the rest of the file"] = rec.cut
    return summary
