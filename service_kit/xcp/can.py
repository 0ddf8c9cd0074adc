"""XCP on CAN (ASAM MCD-1 XCP on CAN): one packet per classic CAN frame, on
the rig's python-can bus, with two identifiers of its own.

The master sends its commands on ``id_master`` (master -> slave), the slave
answers and sends its DAQ packets on ``id_slave`` (slave -> master); both are
11-bit identifiers the rig's CANopen network leaves free
(:func:`check_identifiers` refuses the rig's COB-IDs and the LSS pair). A
frame's data is the packet (no header, no counter): MAX_CTO = MAX_DTO = 8,
so a DOWNLOAD carries at most 6 bytes (a FLOAT64 parameter takes two,
:mod:`.partial`) and a DAQ packet at most 7 data bytes after its PID. A
master may pad its frames to 8 bytes (the slave reads only its fields);
the slave's frames have the packet's length.

A frame the bus does not take at once is a DAQ overload (counted, dropped,
never retried), as on Ethernet.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Final

import can

from protocol.can_map import cob_ids
from service_kit.xcp.server import QUEUE_CAPACITY, Server
from service_kit.xcp.slave import Slave

__all__ = ["CAN_MAX_CTO", "CAN_MAX_DTO", "LSS_COB_IDS", "CanServer", "IdentifierError", "check_identifiers"]

CAN_MAX_CTO: Final = 8
CAN_MAX_DTO: Final = 8
LSS_COB_IDS: Final = (0x7E4, 0x7E5)
"""CiA 305 layer setting services (slave -> master, master -> slave): kept free for them."""
MAX_FRAMES: Final = 256
"""Frames read in one turn of the thread before it looks at the DAQ queue again."""
SEND_TIMEOUT_S: Final = 0.0


class IdentifierError(ValueError):
    """An XCP identifier pair the rig's bus cannot carry (one line: the setting and why)."""


def check_identifiers(pairs: dict[str, tuple[int, int]], node_id: int) -> None:
    """Refuse identifiers that collide with the rig's CANopen COB-IDs (node ``node_id``), carry
    its node id in their low 7 bits, are the LSS pair, each other, or lie outside 11 bits. ``pairs``: a name (the setting) -> (master, slave)."""
    taken = {cob: f"the CANopen {name} COB-ID" for name, cob in cob_ids(node_id).items()}
    taken.update({cob: "the CANopen LSS COB-ID" for cob in LSS_COB_IDS})
    for name, (master, slave) in pairs.items():
        for which, cob in (("master", master), ("slave", slave)):
            if not 0 < cob <= 0x7FF:
                raise IdentifierError(f"{name}: {which} identifier 0x{cob:X} is not an 11-bit CAN identifier (1..0x7FF)")
            if cob in taken:
                raise IdentifierError(f"{name}: {which} identifier 0x{cob:03X} is {taken[cob]}")
            if cob & 0x7F == node_id:  # the node would take it for an unknown COB-ID of its own (counted malformed)
                raise IdentifierError(f"{name}: {which} identifier 0x{cob:03X} carries the CANopen node id {node_id} in its low 7 bits")
        if master == slave:
            raise IdentifierError(f"{name}: master and slave identifiers are both 0x{master:03X}")
        taken.update({master: f"{name}'s master identifier", slave: f"{name}'s slave identifier"})


class CanServer(Server):
    """Serves ``slave`` on ``bus``: commands on ``id_master``, answers and DTOs on ``id_slave``.
    The server owns the bus (closed with it)."""

    name = "xcp-can"

    def __init__(self, slave: Slave, bus: can.BusABC, id_master: int, id_slave: int, capacity: int = QUEUE_CAPACITY) -> None:
        super().__init__(slave, None, capacity)
        self.bus = bus
        self.id_master = id_master
        self.id_slave = id_slave
        bus.set_filters([{"can_id": id_master, "can_mask": 0x7FF, "extended": False}])

    def _frames(self, timeout: float) -> Iterable[can.Message]:
        for i in range(MAX_FRAMES):  # bounded: a flood must not starve the DAQ queue
            msg = self.bus.recv(timeout if i == 0 else 0.0)
            if msg is None:
                return
            yield msg

    def _serve(self, timeout: float) -> None:
        for msg in self._frames(timeout):
            if msg.arbitration_id != self.id_master or msg.is_extended_id or msg.is_error_frame:
                continue  # a bus without hardware filters hands over every frame
            if msg.is_remote_frame or msg.is_fd or msg.dlc > CAN_MAX_CTO:
                self.counters.malformed += 1
                continue
            response = self.slave.handle(bytes(msg.data[: msg.dlc]))
            if response is not None:
                self._send(response)

    def _send(self, packet: bytes) -> bool:
        try:
            self.bus.send(can.Message(arbitration_id=self.id_slave, data=packet, is_extended_id=False), timeout=SEND_TIMEOUT_S)
            return True
        except can.CanError:
            return False

    def _send_dto(self, packet: bytes) -> bool:
        return self._send(packet)

    def _close_sockets(self) -> None:
        self.bus.shutdown()
