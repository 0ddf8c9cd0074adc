"""The node's own CAN error state reported as CiA 301 says (docs/can-errors.md).

A CAN controller tells its host whether it is error active, error passive
or bus off (ISO 11898-1 fault confinement; :mod:`service_kit.can_wire.error_state`).
CiA 301's emergency codes for it:

- 0x8120 "CAN in error passive mode": raised on entering error passive, so
  the error register 0x1001 has its communication bit (bit 4) and the
  generic bit (bit 0) set while the node is not error active;
- 0x8140 "recovered from bus off": sent once the controller is back on the
  bus after bus off (nothing can be sent while bus off);
- 0x0000 "error reset or no error": once error active again, with the
  register cleared (if no other fault is active).

Only a bus that can tell its error state feeds this (a ``ralfwire`` bus's
``can_error_state``); on any other bus nothing here runs.
"""

from __future__ import annotations

from typing import Final

from plant_emulator.canopen_node.emcy import EmcyProducer
from protocol.can_map import EmcyCode
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.wire_errors import error_state_reader

__all__ = ["CanStateReporter", "error_state_reader"]

PASSIVE: Final = int(EmcyCode.CAN_ERROR_PASSIVE)
RECOVERED: Final = int(EmcyCode.CAN_BUS_OFF_RECOVERED)


class CanStateReporter:
    """Turns the controller's error state, read at each :meth:`update`, into EMCYs."""

    def __init__(self, emcy: EmcyProducer) -> None:
        self.emcy = emcy
        self.state = ErrorState.ACTIVE
        """The state last seen."""
        self._was_bus_off = False

    def update(self, state: ErrorState) -> None:
        """Called with the current state as often as the node likes; acts on changes only
        (:meth:`EmcyProducer.set_fault` sends nothing for a fault already so; a fault
        an NMT reset cleared while the node is still error passive is raised again)."""
        self.state = state
        if state is ErrorState.BUS_OFF:
            self._was_bus_off = True
            if PASSIVE not in self.emcy.faults:  # passed through error passive unseen: recorded, not sendable
                self.emcy.faults[PASSIVE] = b""
                self.emcy.record(PASSIVE, b"")
            return
        if self._was_bus_off:
            self._was_bus_off = False
            self.emcy.faults.pop(PASSIVE, None)
            self.emcy.set_fault(RECOVERED, True)
            self.emcy.set_fault(RECOVERED, False)
        self.emcy.set_fault(PASSIVE, state is ErrorState.PASSIVE)
