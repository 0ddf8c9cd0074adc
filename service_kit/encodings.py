"""The contract's payload encodings (:mod:`protocol.encodings`) as zenoh
encoding objects, for ``session.declare_publisher(key, encoding=JSON)``."""

from __future__ import annotations

from typing import Final

import zenoh

from protocol.encodings import BATCH_MIME, BATCH_SCHEMA, JSON_MIME, TF_MIME, TF_SCHEMA

JSON: Final[zenoh.Encoding] = zenoh.Encoding.APPLICATION_JSON
"""Every control message (BlockFlag, Interrupt, Health, ...)."""
BATCH: Final[zenoh.Encoding] = zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(BATCH_SCHEMA)
"""The binary sample batch of :mod:`protocol.batch_codec`."""

TF: Final[zenoh.Encoding] = zenoh.Encoding.APPLICATION_OCTET_STREAM.with_schema(TF_SCHEMA)
"""The binary transfer-function snapshot of :mod:`protocol.tf_codec`."""

assert str(JSON) == JSON_MIME and str(BATCH) == BATCH_MIME and str(TF) == TF_MIME, "contract and zenoh encodings disagree"
