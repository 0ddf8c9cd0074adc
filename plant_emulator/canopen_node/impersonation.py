"""Frames on the node's own COB-IDs: echoes of its own on a bus that hands them back, or another
node using its identifiers, answered with EMCY CAN_ID_COLLISION (docs/canopen.md, "Behaviour on
the bus": Frames on our own COB-IDs)."""

from __future__ import annotations

import math
from typing import Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.emcy import EmcyProducer
from plant_emulator.canopen_node.transmit import NodeLog, Outbox
from protocol.can_map import EmcyCode, encode_collision_evidence

COLLISION_EMCY_INTERVAL_S: Final[float] = 0.1
"""EMCY CAN_ID_COLLISION is sent for the first frame on our own COB-IDs that we did not send and then
at most once per this interval, each with that frame's evidence (further ones only counted)."""
COLLISION_CLEAR_S: Final[float] = 1.0
"""CAN_ID_COLLISION is reset (EMCY 0x0000) at the first SYNC this long after the last such frame."""
_CAN_ID_COLLISION: Final = int(EmcyCode.CAN_ID_COLLISION)


class CollisionMonitor:
    """Tells echoes from impersonation; raises and clears CAN_ID_COLLISION."""

    def __init__(self, own_kind: dict[int, str], outbox: Outbox, emcy: EmcyProducer, counters: NodeCounters, log: NodeLog) -> None:
        self.own_kind = own_kind
        """Own COB-ID -> its kind (emcy, tpdo1 ... heartbeat)."""
        self.outbox = outbox
        self.emcy = emcy
        self.counters = counters
        self.log = log
        self.last: float | None = None
        """When the last frame that was not ours arrived (None: none since the last clear)."""
        self._emcy_at = -math.inf

    def frame(self, cob_id: int, data: bytes, now: float) -> None:
        """A frame on one of our own COB-IDs: our echo, or another node impersonating us."""
        memory = self.outbox.echoes
        if memory is not None:
            sent = memory[cob_id]
            for i, d in enumerate(sent):
                if d == data:  # echoes come back in send order: the ones before were lost
                    for _ in range(i + 1):
                        sent.popleft()
                    self.counters.rx["own_cob_id"] += 1
                    return
        kind = self.own_kind[cob_id]
        self.counters.impersonated[kind] += 1
        self.last = now
        self.log.limited(
            f"impersonated:{kind}",
            now,
            "node %d: a %s frame id 0x%03X [%s] this node did not send: another node uses its COB-IDs (%d such frames so far)",
            self.log.node_id,
            kind,
            cob_id,
            data.hex(" "),
            sum(dict.copy(self.counters.impersonated).values()),
        )
        if now - self._emcy_at >= COLLISION_EMCY_INTERVAL_S:
            self._emcy_at = now
            vendor = encode_collision_evidence(cob_id, data)
            self.emcy.faults[_CAN_ID_COLLISION] = vendor
            self.emcy.record(_CAN_ID_COLLISION, vendor)
            self.emcy.send(_CAN_ID_COLLISION, vendor)  # each with its frame's evidence (rate-bounded), not once per episode

    def check_clear(self, now: float) -> None:
        """At a SYNC: reset CAN_ID_COLLISION once no such frame came for :data:`COLLISION_CLEAR_S`."""
        last = self.last
        if last is not None and now - last >= COLLISION_CLEAR_S:
            self.last = None
            self.emcy.set_fault(_CAN_ID_COLLISION, False)
