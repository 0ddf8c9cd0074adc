"""Reading a recording back with the ``mcap`` library: the run's metadata,
its messages by topic in log-time order, and the series the replay and the
plots use (batches, interrupts, truth, TF downloads, CAN frames)."""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap import records as mcap_records
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from workbench.recording import schemas


@dataclass(frozen=True)
class Recorded:
    """One message: its topic, schema name, log and publish time (ns) and decoded JSON."""

    topic: str
    schema: str
    log_time_ns: int
    publish_time_ns: int
    data: dict[str, Any]


@dataclass
class Recording:
    """A whole recording in memory (runs of minutes: tens of MB of JSON)."""

    path: Path
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    messages: list[Recorded] = field(default_factory=list)
    cut: str = ""
    """Why and where the file ends early (a run cut by a signal leaves no summary); empty for a whole file."""

    @classmethod
    def load(cls, path: str | Path, only: Iterable[str] | None = None) -> Recording:
        """Read ``path``; ``only``: topic suffixes to keep (``"dsp/batch"``, ``"can"``, ...), all by default.
        (A long run's CAN frames are most of the file: leave them out when they are not needed.)"""
        rec = cls(Path(path))
        wanted = None if only is None else tuple(only)
        try:
            rec._load_indexed(wanted)
        except Exception:  # noqa: BLE001 -- no usable summary (a run cut by a signal): read on up to the cut
            rec.metadata, rec.messages = {}, []
            rec.cut = read_up_to_cut(rec.path, rec.metadata, rec.messages, wanted)
        return rec

    def _load_indexed(self, wanted: tuple[str, ...] | None) -> None:
        """The whole file through its summary (a file closed as it should be)."""
        rec = self
        with open(rec.path, "rb") as f:
            reader = make_reader(f)
            for meta in reader.iter_metadata():
                rec.metadata[meta.name] = dict(meta.metadata)
            summary = reader.get_summary()
            topics = None
            if wanted is not None and summary is not None:
                topics = [
                    c.topic for c in summary.channels.values() if any(c.topic == schemas.CAN_TOPIC if w == "can" else c.topic.endswith("/" + w) for w in wanted)
                ]
            for schema, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
                rec.messages.append(Recorded(channel.topic, schema.name if schema else "", message.log_time, message.publish_time, json.loads(message.data)))

    # -- metadata -----------------------------------------------------------------------
    @property
    def rig_id(self) -> str:
        run = self.metadata.get("ralf.run", {})
        if "rig_id" in run:
            return run["rig_id"]
        for m in self.messages:
            parts = m.topic.strip("/").split("/")
            if len(parts) >= 3 and parts[0] == "ralf":
                return parts[1]
        return "default"

    def settings(self, service: str) -> dict[str, Any]:
        """A service's recorded settings (decoded from the metadata's JSON values)."""
        raw = self.metadata.get(f"ralf.settings.{service}", {})
        out: dict[str, Any] = {}
        for k, v in raw.items():
            try:
                out[k] = json.loads(v)
            except json.JSONDecodeError:
                out[k] = v
        return out

    # -- messages -----------------------------------------------------------------------
    def topic(self, suffix: str) -> str:
        if suffix in ("can", "can/bus_load"):  # the rig's own topics, outside any rig's keys
            return schemas.CAN_TOPIC if suffix == "can" else schemas.CAN_BUS_LOAD_TOPIC
        return f"/ralf/{self.rig_id}/{suffix}"

    def iter(self, *suffixes: str) -> Iterator[Recorded]:
        topics = {self.topic(s) for s in suffixes}
        return (m for m in self.messages if m.topic in topics)

    def data(self, suffix: str) -> list[dict[str, Any]]:
        return [m.data for m in self.iter(suffix)]

    def topics(self) -> dict[str, int]:
        counts: dict[str, int] = {}
        for m in self.messages:
            counts[m.topic] = counts.get(m.topic, 0) + 1
        return counts

    # -- series ---------------------------------------------------------------------------
    def truth(self) -> dict[str, np.ndarray]:
        """Ground truth as arrays: ``sim_time_s``, ``modal_frequencies_hz`` (n, modes), ``deflections_in``, ``theta_rad`` (n, 2)."""
        rows = self.data("plant/truth")
        if not rows:
            return {}
        modes = min(len(r["modal_frequencies_hz"]) for r in rows)
        return {
            "sim_time_s": np.array([r["sim_time_s"] for r in rows], dtype=float),
            "modal_frequencies_hz": np.array([r["modal_frequencies_hz"][:modes] for r in rows], dtype=float).reshape(len(rows), modes),
            "deflections_in": np.array([r["deflections_in"] for r in rows], dtype=float),
            "theta_rad": np.array([r["theta_rad"] for r in rows], dtype=float),
            "payload_attached": np.array([r["payload_attached"] for r in rows], dtype=bool),
        }

    def interrupts(self) -> list[dict[str, Any]]:
        return self.data("dsp/interrupt")

    def tf_downloads(self) -> list[dict[str, Any]]:
        return self.data("controller/tf")

    def can_frames(self) -> list[dict[str, Any]]:
        return self.data("can")


def _wanted(topic: str, wanted: tuple[str, ...] | None) -> bool:
    return wanted is None or any(topic == schemas.CAN_TOPIC if w == "can" else topic.endswith("/" + w) for w in wanted)


def read_up_to_cut(path: Path, metadata: dict[str, dict[str, str]], messages: list[Recorded], wanted: tuple[str, ...] | None = None) -> str:
    """Read a recording front to back with the ``mcap`` library's stream reader
    (no summary, no seeking), keeping every record before the first one that
    cannot be read (a truncated chunk, a length past the end); messages are
    put in log-time order. Returns where the file ended, one line ("" when it
    read to its footer)."""
    channels: dict[int, tuple[str, str]] = {}
    schema_names: dict[int, str] = {}
    ended = ""
    with open(path, "rb") as fh:
        try:
            for record in StreamReader(fh, record_size_limit=max(1, path.stat().st_size)).records:
                if isinstance(record, mcap_records.Schema):
                    schema_names[record.id] = record.name
                elif isinstance(record, mcap_records.Channel):
                    channels[record.id] = (record.topic, schema_names.get(record.schema_id, ""))
                elif isinstance(record, mcap_records.Message):
                    topic, schema = channels.get(record.channel_id, ("", ""))
                    if topic and _wanted(topic, wanted):
                        messages.append(Recorded(topic, schema, record.log_time, record.publish_time, json.loads(record.data)))
                elif isinstance(record, mcap_records.Metadata):
                    metadata[record.name] = dict(record.metadata)
        except Exception as exc:  # noqa: BLE001 -- the first unreadable record is where the file ends
            ended = type(exc).__name__
    messages.sort(key=lambda m: m.log_time_ns)
    if not ended:
        return ""
    span = (messages[-1].log_time_ns - messages[0].log_time_ns) / 1e9 if messages else 0.0
    return f"cut short ({ended} after byte-complete records): {len(messages)} messages read, {span:.1f} s of log time"
