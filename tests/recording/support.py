"""What the recording tests share: reading a file back with the mcap library,
every message validated against its channel's JSON schema."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jsonschema
from mcap.reader import make_reader

CHANNELS_OF_A_RUN = (
    "dsp/batch",
    "dsp/interrupt",
    "dsp/flag",
    "dsp/config",
    "plant/truth",
    "controller/tf",
    "controller/status",
    "health/controller",
    "health/dsp",
    "health/plant",
)
"""Keys below ``ralf/<rig>/`` every recorded run of a rig carries."""


@dataclass
class Validated:
    counts: dict[str, int]
    """Messages per topic."""
    metadata: dict[str, dict[str, str]]
    encodings: dict[str, str]
    """Topic -> the zenoh encoding its channel records."""


def read_validated(path: str | Path) -> Validated:
    """Every message of ``path``, each validated against its channel's schema (jsonschema, not ours)."""
    counts: dict[str, int] = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        validators: dict[int, Any] = {}
        for schema, channel, message in reader.iter_messages():
            assert schema is not None and schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if schema.id not in validators:
                validators[schema.id] = jsonschema.Draft202012Validator(json.loads(schema.data))
            validators[schema.id].validate(json.loads(message.data))
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        summary = reader.get_summary()
    assert summary is not None
    encodings = {ch.topic: ch.metadata["zenoh_encoding"] for ch in summary.channels.values() if "zenoh_encoding" in ch.metadata}
    return Validated(counts, metadata, encodings)
