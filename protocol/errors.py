"""Error types shared by every program: each names what was wrong with the input."""

from __future__ import annotations


class ProtocolError(ValueError):
    """A message that crossed a process boundary and does not follow the contract."""


class FrameError(ProtocolError):
    """A CAN frame with the wrong length, an unknown command or an out-of-range field."""


class BatchDecodeError(ProtocolError):
    """A sample-batch payload that is truncated or inconsistent with its header."""


class TfDecodeError(ProtocolError):
    """A transfer-function snapshot payload that breaks its binary layout (protocol/tf_codec.py)."""


class ConfigError(ValueError):
    """A configuration value that cannot work (caught at start-up, never mid-run)."""


class TransportError(ConfigError, ConnectionError):
    """A zenoh session or CAN bus that cannot be opened as configured (a bad
    endpoint, a port in use, no such interface): reported on one line, exit 2."""
