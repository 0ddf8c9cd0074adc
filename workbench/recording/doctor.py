"""``ralf-hil doctor RUN.mcap``: a structural check of a recording, in the
spirit of the ``mcap doctor`` command of the MCAP project's CLI (a Go
binary, not installable from the Python registries), built on the ``mcap``
library's stream reader rather than on our own reader:

* every CRC the file carries (chunks, data section, summary) verifies;
* every message's channel, and every channel's schema, is declared before use;
* each chunk's messages lie within the chunk's declared time range;
* the Statistics record's counts (messages, channels, schemas, chunks,
  metadata, per-channel messages) and time range equal what the file holds;
* the summary's channels and schemas equal those of the data section.

Each problem is one line; an empty list means the file is sound. A file
that holds no message is a problem too (:data:`MIN_MESSAGES`): there is
nothing in it to check, and nothing to plot or replay.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from mcap import records
from mcap.exceptions import EndOfFile, RecordLengthLimitExceeded
from mcap.stream_reader import StreamReader, breakup_chunk

MIN_MESSAGES = 1
"""Messages a recording must hold for ``ralf-hil doctor`` to call it sound."""


@dataclass
class Examination:
    """What :func:`examine` found: the problems and what it checked."""

    problems: list[str]
    messages: int = 0
    channels: int = 0
    chunks: int = 0

    def line(self) -> str:
        return f"{self.messages} messages on {self.channels} channels in {self.chunks} chunks checked"


def check(path: str | Path) -> list[str]:
    """The problems of the MCAP file at ``path`` (empty: none found)."""
    return examine(path).problems


def examine(path: str | Path) -> Examination:
    """The problems of the MCAP file at ``path`` and the counts of what was checked."""
    found = Examination([])
    found.problems = _check(path, found)
    return found


def _check(path: str | Path, found: Examination) -> list[str]:
    problems: list[str] = []
    schemas: set[int] = set()
    channels: dict[int, str] = {}
    per_channel: Counter[int] = Counter()
    counts: Counter[str] = Counter()
    first: int | None = None
    last: int | None = None
    statistics: records.Statistics | None = None
    summary_channels: set[int] = set()
    summary_schemas: set[int] = set()
    in_summary = False
    try:
        with open(path, "rb") as fh:
            for record in StreamReader(fh, emit_chunks=True, validate_crcs=True).records:
                if isinstance(record, records.Chunk):
                    counts["chunks"] += 1
                    _check_chunk(record, schemas, channels, per_channel, problems)
                    for t in _chunk_times(record):
                        first = t if first is None else min(first, t)
                        last = t if last is None else max(last, t)
                elif isinstance(record, records.DataEnd):
                    in_summary = True
                elif isinstance(record, records.Schema):
                    (summary_schemas if in_summary else schemas).add(record.id)
                    counts["schemas"] += 0 if in_summary else 1
                elif isinstance(record, records.Channel):
                    if in_summary:
                        summary_channels.add(record.id)
                    else:
                        _declare_channel(record, schemas, channels, problems)
                        counts["channels"] += 1
                elif isinstance(record, records.Message):
                    _check_message(record, channels, per_channel, problems)
                    first = record.log_time if first is None else min(first, record.log_time)
                    last = record.log_time if last is None else max(last, record.log_time)
                elif isinstance(record, records.Metadata):
                    counts["metadata"] += 1
                elif isinstance(record, records.Statistics):
                    statistics = record
    except Exception as exc:  # noqa: BLE001 -- any failure to read is the finding: bad CRC, truncation, corrupt compression
        found.messages, found.channels, found.chunks = sum(per_channel.values()), len(channels), counts["chunks"]
        what = f"{type(exc).__name__}: {exc}".rstrip(": ")
        if isinstance(exc, (EndOfFile, RecordLengthLimitExceeded)) and statistics is None and counts["chunks"] + sum(per_channel.values()) > 0:
            # A recording cut by a signal: sound up to its last whole record.
            span = 0.0 if first is None or last is None else (last - first) / 1e9
            return [
                *problems,
                f"cut short: the file ({_size(path)} bytes) ends inside a record ({what}); {sum(per_channel.values())} messages in "
                f"{counts['chunks']} whole chunks before it, {span:.1f} s of log time; no summary (plot and replay read it up to the cut)",
            ]
        return [*problems, f"unreadable: {what}"]
    found.messages, found.channels, found.chunks = sum(per_channel.values()), len(channels), counts["chunks"]
    if found.messages < MIN_MESSAGES:
        problems.append(f"holds {found.messages} messages (at least {MIN_MESSAGES} needed): nothing to check, plot or replay")
    if statistics is None:
        problems.append("no Statistics record in the summary")
    else:
        _check_statistics(statistics, counts, per_channel, first, last, problems)
    if summary_channels and summary_channels != set(channels):
        problems.append(f"summary channels {sorted(summary_channels)} differ from the data section's {sorted(channels)}")
    if summary_schemas and summary_schemas != schemas:
        problems.append(f"summary schemas {sorted(summary_schemas)} differ from the data section's {sorted(schemas)}")
    return problems


def _declare_channel(record: records.Channel, schemas: set[int], channels: dict[int, str], problems: list[str]) -> None:
    if record.schema_id != 0 and record.schema_id not in schemas:
        problems.append(f"channel {record.id} ({record.topic}) uses schema {record.schema_id} before it is declared")
    channels[record.id] = record.topic


def _check_message(record: records.Message, channels: dict[int, str], per_channel: Counter[int], problems: list[str]) -> None:
    if record.channel_id not in channels:
        problems.append(f"message on undeclared channel {record.channel_id} at {record.log_time} ns")
    per_channel[record.channel_id] += 1


def _inner(chunk: records.Chunk) -> list[records.McapRecord]:
    """The records of a chunk, its CRC checked (the library's own chunk decoding)."""
    return breakup_chunk(chunk, validate_crc=True)


def _chunk_times(chunk: records.Chunk) -> list[int]:
    return [r.log_time for r in _inner(chunk) if isinstance(r, records.Message)]


def _check_chunk(chunk: records.Chunk, schemas: set[int], channels: dict[int, str], per_channel: Counter[int], problems: list[str]) -> None:
    for record in _inner(chunk):
        if isinstance(record, records.Schema):
            schemas.add(record.id)
        elif isinstance(record, records.Channel):
            _declare_channel(record, schemas, channels, problems)
        elif isinstance(record, records.Message):
            _check_message(record, channels, per_channel, problems)
            if not chunk.message_start_time <= record.log_time <= chunk.message_end_time:
                problems.append(f"message at {record.log_time} ns outside its chunk [{chunk.message_start_time}, {chunk.message_end_time}]")


def _check_statistics(
    stats: records.Statistics, counts: Counter[str], per_channel: Counter[int], first: int | None, last: int | None, problems: list[str]
) -> None:
    total = sum(per_channel.values())
    wanted = {
        "message_count": (stats.message_count, total),
        "channel_count": (stats.channel_count, len(per_channel | Counter(dict.fromkeys(stats.channel_message_counts, 0)))),
        "chunk_count": (stats.chunk_count, counts["chunks"]),
        "metadata_count": (stats.metadata_count, counts["metadata"]),
    }
    for name, (declared, found) in wanted.items():
        if declared != found:
            problems.append(f"Statistics {name} {declared} but the file holds {found}")
    if dict(stats.channel_message_counts) != {k: v for k, v in per_channel.items() if v}:
        problems.append("Statistics per-channel message counts differ from the messages in the file")
    if total and (stats.message_start_time, stats.message_end_time) != (first, last):
        problems.append(f"Statistics time range [{stats.message_start_time}, {stats.message_end_time}] but messages span [{first}, {last}]")


def _size(path: str | Path) -> str:
    try:
        return str(Path(path).stat().st_size)
    except OSError:
        return "?"
