"""How waiting for the plant node ends when it does not answer."""

from __future__ import annotations


class PlantFault(RuntimeError):
    """The plant node stopped answering (no heartbeat, no TPDO)."""


class StopRequested(Exception):
    """SIGINT/SIGTERM arrived while waiting for the plant: not a fault."""
