"""The node's outgoing side: the frames one call produces, and the diagnostics every part shares.

:class:`Outbox` collects the frames a call of the node produces, in order,
stamped with the call's time, and remembers them per COB-ID while the bus
hands a sender its frames back (:class:`~.impersonation.CollisionMonitor`
tells those echoes from another node's frames). :class:`NodeLog` counts and
logs what goes wrong without flooding the log: malformed frames once per
kind, application callbacks that raise once per callback, repeated
conditions at most once per interval."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from typing import Any, Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.frames import Frame

log = logging.getLogger("plant_emulator.canopen_node.node")

ECHO_MEMORY: Final[int] = 64
"""Frames sent and not yet seen again, per COB-ID, on a bus that hands them back (udp_multicast)."""
LOG_INTERVAL_S: Final[float] = 10.0
"""Impersonated frames and SDO writes of communication objects are logged at most once per this interval per kind."""


class Outbox:
    """Frames to transmit, in the order the node made them."""

    __slots__ = ("counters", "echoes", "frames", "now")

    def __init__(self, counters: NodeCounters) -> None:
        self.counters = counters
        self.frames: list[Frame] = []
        self.now = 0.0
        """The time of the call in progress: every frame made in it carries it."""
        self.echoes: dict[int, deque[bytes]] | None = None
        """Frames sent and not yet seen again, per own COB-ID, while the bus echoes (else None)."""

    def emit(self, cob_id: int, data: bytes, kind: str) -> None:
        self.counters.tx[kind] += 1
        self.frames.append(Frame(cob_id, data, self.now))
        if self.echoes is not None:
            self.echoes[cob_id].append(data)

    def take(self) -> list[Frame]:
        out, self.frames = self.frames, []
        return out

    def expect_echoes(self, own_cob_ids: frozenset[int] | None) -> None:
        """Start (the node's own COB-IDs) or stop (None) remembering what was sent;
        frames made before (the boot-up, not sent yet) count as sent."""
        self.echoes = {cob_id: deque(maxlen=ECHO_MEMORY) for cob_id in own_cob_ids} if own_cob_ids is not None else None
        if self.echoes is not None:
            for f in self.frames:
                if f.arbitration_id in self.echoes:
                    self.echoes[f.arbitration_id].append(f.data)


class NodeLog:
    """Counting and rate-limited logging shared by the node's parts."""

    __slots__ = ("_logged", "_logged_at", "counters", "node_id")

    def __init__(self, node_id: int, counters: NodeCounters) -> None:
        self.node_id = node_id
        self.counters = counters
        self._logged: set[str] = set()
        self._logged_at: dict[str, float] = {}

    def once(self, key: str, fmt: str, *args: object) -> None:
        if key not in self._logged:
            self._logged.add(key)
            log.warning(fmt, *args)

    def limited(self, key: str, now: float, fmt: str, *args: object, level: int = logging.WARNING) -> None:
        last = self._logged_at.get(key)
        if last is None or now - last >= LOG_INTERVAL_S:
            self._logged_at[key] = now
            log.log(level, fmt, *args)

    def malformed(self, kind: str, cob_id: int, data: bytes, why: str) -> None:
        self.counters.malformed[kind] += 1
        self.once(
            kind,
            "node %d: ignored %s frame id 0x%03X data [%s]: %s (further ones are only counted)",
            self.node_id,
            kind,
            cob_id,
            data.hex(" "),
            why,
        )

    def call_app(self, name: str, fn: Callable[..., Any], *args: Any) -> Any:
        try:
            return fn(*args)
        except Exception:  # noqa: BLE001 - the app's bug must not take the bus down
            self.app_failed(name)
            return None

    def app_failed(self, name: str) -> None:
        """An application callback raised (called from inside its ``except``): counted, logged once."""
        self.counters.app_errors += 1
        if f"app:{name}" not in self._logged:
            self._logged.add(f"app:{name}")
            log.exception("node %d: application callback %s failed (further failures only counted)", self.node_id, name)
