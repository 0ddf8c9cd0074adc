"""zenoh encodings of the contract's payloads, so any zenoh tool (the REST
plugin, ``z_sub``, a recorder) can tell what a sample carries without
knowing the key:

* every pydantic message (:mod:`protocol.messages`) travels as
  :data:`JSON` (``application/json``);
* a sample batch (:mod:`protocol.batch_codec`) as :data:`BATCH`
  (``application/octet-stream;ralf-batch-v1``: binary, layout version 1).

Publishers pass them at declaration, e.g.
``session.declare_publisher(key, encoding=JSON)``; :func:`encoding_for`
gives the one a key of the contract uses.
"""

from __future__ import annotations

from typing import Final

import zenoh

from protocol.batch_codec import VERSION as BATCH_VERSION

JSON: Final[zenoh.Encoding] = zenoh.Encoding.APPLICATION_JSON
"""Every control message (BlockFlag, Interrupt, Health, ...)."""
BATCH_SCHEMA: Final[str] = f"ralf-batch-v{BATCH_VERSION}"
BATCH: Final[zenoh.Encoding] = zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(BATCH_SCHEMA)
"""The binary sample batch of :mod:`protocol.batch_codec`."""


def encoding_for(key: str) -> zenoh.Encoding:
    """The encoding the contract uses on ``key`` (a full ``ralf/<rig>/...`` key)."""
    return BATCH if key.endswith("/dsp/batch") else JSON
