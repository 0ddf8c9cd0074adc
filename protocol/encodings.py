"""Encodings of the contract's payloads on zenoh, as the MIME strings any
zenoh tool (the REST plugin, ``z_sub``, a recorder) reads off a sample, so it
can tell what a sample carries without knowing the key:

* every pydantic message (:mod:`protocol.messages`) travels as
  :data:`JSON_MIME` (``application/json``);
* a sample batch (:mod:`protocol.batch_codec`) as :data:`BATCH_MIME`
  (``application/octet-stream;ralf-batch-v1``: binary, layout version 1);
* a transfer-function snapshot (:mod:`protocol.tf_codec`, on ``dsp/tf`` and
  ``controller/tf``) as :data:`TF_MIME` (``application/octet-stream;ralf-tf-v1``).

The contract names them; :mod:`service_kit.encodings` turns them into zenoh
encoding objects for publishers (the contract itself imports no transport).
"""

from __future__ import annotations

from typing import Final

from protocol.batch_codec import VERSION as BATCH_VERSION
from protocol.tf_codec import VERSION as TF_VERSION

JSON_MIME: Final[str] = "application/json"
"""Every control message (BlockFlag, Interrupt, Health, ...)."""
BATCH_SCHEMA: Final[str] = f"ralf-batch-v{BATCH_VERSION}"
BATCH_MIME: Final[str] = f"application/octet-stream;{BATCH_SCHEMA}"
"""The binary sample batch of :mod:`protocol.batch_codec`."""


TF_SCHEMA: Final[str] = f"ralf-tf-v{TF_VERSION}"
TF_MIME: Final[str] = f"application/octet-stream;{TF_SCHEMA}"
"""The binary transfer-function snapshot of :mod:`protocol.tf_codec`."""


def mime_for(key: str) -> str:
    """The encoding the contract uses on ``key`` (a full ``ralf/<rig>/...`` key)."""
    if key.endswith("/dsp/batch"):
        return BATCH_MIME
    if key.endswith(("/dsp/tf", "/controller/tf")):
        return TF_MIME
    return JSON_MIME
