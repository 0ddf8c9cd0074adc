"""CAN error states the controller notices (docs/can-errors.md): the plant
node's, from its EMCYs (CiA 301 0x8120 "CAN in error passive mode", 0x8140
"recovered from bus off", cleared by the error reset 0x0000 naming them),
and its own CAN controller's, when its bus can tell it (a ``ralfwire`` bus;
:func:`service_kit.can_wire.wire_errors.error_state_reader`).

While either is not error active the ``can_error_passive`` monitor is on
(:class:`controller.tick_policy.TickPolicy`); its policy
``policies.can_error_passive`` (default ``count``) decides what the
controller does: count it, warn, degrade (the fallback parameters) or stop.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Final

import can

from controller.plant_link_counters import PlantLinkCounters
from protocol import can_map
from protocol.errors import ConfigError
from service_kit.can_wire.error_state import ErrorState
from service_kit.can_wire.scenario_errors import CanErrorsNeedWire, attach
from service_kit.can_wire.wire_errors import error_state_reader
from service_kit.link_faults import Scenario

PASSIVE: Final = int(can_map.EmcyCode.CAN_ERROR_PASSIVE)
RECOVERED: Final = int(can_map.EmcyCode.CAN_BUS_OFF_RECOVERED)
COMMUNICATION_CODES: Final = frozenset({PASSIVE, RECOVERED})


class CanErrorWatch:
    """The plant's reported CAN error state and the controller's own (module docstring)."""

    def __init__(self, bus: can.BusABC, counters: PlantLinkCounters) -> None:
        self.counters = counters
        self.plant_reports: str | None = None
        """The plant's last EMCY on its CAN error state not yet reset (None: none)."""
        self._latched: str | None = None
        """The plant's first such EMCY since :meth:`condition` last looked: an episode that began and
        ended between two ticks (error passive, bus off and recovered) still turns the monitor on once."""
        self._read_own: Callable[[], ErrorState] | None = error_state_reader(bus)
        self._own = ErrorState.ACTIVE

    def on_emcy(self, emcy: can_map.Emergency) -> None:
        """Every EMCY from the plant: its CAN error state reports counted, and their reset."""
        if emcy.code == PASSIVE:
            self.counters.plant_can_error_passive += 1
            self.plant_reports = f"the plant node is CAN error passive (EMCY 0x{PASSIVE:04x})"
            self._latched = self._latched or self.plant_reports
        elif emcy.code == RECOVERED:
            self.counters.plant_can_bus_off_recoveries += 1
            self.plant_reports = f"the plant node recovered from CAN bus off (EMCY 0x{RECOVERED:04x})"
            self._latched = self._latched or self.plant_reports
        elif emcy.code == 0 and int.from_bytes(emcy.vendor[:2], "little") in COMMUNICATION_CODES:
            self.plant_reports = None

    def own_state(self) -> ErrorState:
        """The controller's own CAN controller's state now (error active on a bus that cannot tell);
        each entry into error passive or bus off is counted."""
        if self._read_own is None:
            return ErrorState.ACTIVE
        state = self._read_own()
        if state is not self._own:
            if state is ErrorState.PASSIVE and self._own is ErrorState.ACTIVE:
                self.counters.own_can_error_passive += 1
            elif state is ErrorState.BUS_OFF:
                self.counters.own_can_bus_off += 1
            self._own = state
        return state

    def condition(self) -> str | None:
        """What keeps the monitor on, or None when every node seen is error active."""
        latched, self._latched = self._latched, None
        if self._read_own is None and self.plant_reports is None and latched is None:
            return None  # the per-tick case on a bus without error states
        own = self.own_state()
        plant = self.plant_reports if self.plant_reports is not None else latched
        parts = [plant] if plant is not None else []
        if own is not ErrorState.ACTIVE:
            parts.append(f"the controller's CAN controller is {own.value}")
        return "; ".join(parts) or None


def attach_can_errors(bus: can.BusABC | None, scenario: Scenario | None) -> int:
    """The fault scenario's ``can_errors`` on the controller's bus (a ``ralfwire`` bus:
    every bus of its channel shares the wire); any other bus refuses them with one line."""
    try:
        return attach(bus, scenario)
    except CanErrorsNeedWire as exc:
        raise ConfigError(str(exc)) from None
