"""NMT slave (CiA 301): the node's state, the NMT commands it takes and its heartbeat producer
(docs/canopen.md, "Behaviour on the bus": NMT, Heartbeat); what a state change does to the other
parts is :mod:`~.lifecycle`'s."""

from __future__ import annotations

import math
from typing import Final

from plant_emulator.canopen_node.counters import NodeCounters
from plant_emulator.canopen_node.live_config import OD_HEARTBEAT_TIME
from plant_emulator.canopen_node.od import ObjectDictionary, Value
from plant_emulator.canopen_node.transmit import NodeLog, Outbox
from protocol.can_map import NmtCommand, NmtState, encode_heartbeat

EMCY_STATES: Final = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})
"""The states in which the node sends EMCYs and answers SDOs."""


class NmtSlave:
    """The NMT state, NMT command decoding and the heartbeat producer."""

    def __init__(self, od: ObjectDictionary, node_id: int, heartbeat_cob_id: int, outbox: Outbox, counters: NodeCounters, log: NodeLog) -> None:
        self.node_id = node_id
        self.heartbeat_cob_id = heartbeat_cob_id
        self.outbox = outbox
        self.counters = counters
        self.log = log
        self.state = NmtState.BOOT_UP
        self.heartbeat_next: float | None = None
        """When the next heartbeat is due (None: not started; the next timer run starts it)."""
        od.on_write(OD_HEARTBEAT_TIME, 0, self._write_heartbeat)

    def _write_heartbeat(self, value: Value) -> None:
        self.heartbeat_next = None  # restart with the new period (one period from now)

    def command(self, cob_id: int, data: bytes) -> NmtCommand | None:
        """The command of an NMT frame for this node (None: malformed, counted, or for another node)."""
        self.counters.rx["nmt"] += 1
        if len(data) != 2:
            self.log.malformed("nmt_dlc", cob_id, data, f"NMT takes 2 bytes, got {len(data)}")
            return None
        try:
            command = NmtCommand(data[0])
        except ValueError:
            self.log.malformed("nmt_command", cob_id, data, f"unknown NMT command 0x{data[0]:02X}")
            return None
        target = data[1]
        if target > 127:
            self.log.malformed("nmt_node_id", cob_id, data, f"NMT node id {target} outside 0..127")
            return None
        if target not in (0, self.node_id):
            self.counters.rx["nmt_other_node"] += 1
            return None
        return command

    def send_boot_up(self) -> None:
        self.state = NmtState.BOOT_UP
        self.outbox.emit(self.heartbeat_cob_id, encode_heartbeat(NmtState.BOOT_UP), "bootup")
        self.state = NmtState.PRE_OPERATIONAL
        self.heartbeat_next = None

    def start_heartbeat(self, now: float, period: float) -> None:
        """Schedule the first beat one period from now, if none is scheduled."""
        if self.heartbeat_next is None and period > 0:
            self.heartbeat_next = now + period

    def heartbeat(self, now: float, period: float) -> float:
        """Start the heartbeat if it is not running, send it when due; returns
        when it is next due (inf: off)."""
        hb_next = self.heartbeat_next
        if hb_next is None:
            if period > 0:
                self.heartbeat_next = now + period  # first beat one period from now
        elif period > 0 and now >= hb_next:
            self.outbox.emit(self.heartbeat_cob_id, encode_heartbeat(self.state), "heartbeat")
            hb_next += period
            if hb_next <= now:
                self.counters.heartbeat_late += 1
                hb_next = now + period
            self.heartbeat_next = hb_next
        return self.heartbeat_next if period > 0 and self.heartbeat_next is not None else math.inf
