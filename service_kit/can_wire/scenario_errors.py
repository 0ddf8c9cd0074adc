"""A fault scenario's ``can_errors`` (:class:`service_kit.link_faults.CanErrorFault`)
on a ``ralfwire`` wire, or on the simulated rig's wire (docs/can-errors.md).

Each entry becomes an :class:`~service_kit.can_wire.arbitration.ErrorInjection`:
its window ``[from_s, to_s)`` in seconds from ``origin_ns`` on the wire's
clock (simulated seconds on a :class:`~service_kit.can_wire.wire_bus.ManualWireClock`
that starts at 0; on the real-time clock, seconds from when the errors were
attached; on the simulated rig's wire, simulated seconds on the plant
model's axis), its random draws seeded from the scenario's seed and the entry's
index, so a run on a manual clock is repeatable.
"""

from __future__ import annotations

from collections.abc import Sequence

import can

from service_kit.can_wire.arbitration import ErrorInjection
from service_kit.can_wire.wire_bus import WireBus
from service_kit.link_faults import CanErrorFault, Scenario


class CanErrorsNeedWire(ValueError):
    """A scenario with ``can_errors`` for a bus that is neither ``ralfwire`` nor the simulated rig's wire."""


def injections(faults: Sequence[CanErrorFault], seed: int, origin_ns: int = 0) -> list[ErrorInjection]:
    """The wire's injections for ``faults`` (module docstring)."""
    out = []
    for i, f in enumerate(faults):
        out.append(
            ErrorInjection(
                arbitration_id=None if f.identifier == "all" else f.identifier,
                start_ns=origin_ns + round(f.from_s * 1e9),
                end_ns=None if f.to_s is None else origin_ns + round(f.to_s * 1e9),
                every=f.every,
                probability=f.probability,
                seed=(seed * 1_000_003 + i) & 0x7FFF_FFFF,
                count=f.count,
                echo_bits=f.echo_bits,
                first_attempts=f.attempts_per_frame,
            )
        )
    return out


def attach(bus: can.BusABC | None, scenario: Scenario | None) -> int:
    """Puts ``scenario``'s ``can_errors`` on ``bus``'s wire; returns how many.
    A scenario without them changes nothing; with them, a bus that is neither
    ``ralfwire`` nor the simulated rig's wire (its ``inject_can_errors``:
    :class:`workbench.cosim_wire.TimedCanWire`, the one-process lockstep rig's
    controller bus) raises :class:`CanErrorsNeedWire` (one line), never a silent loss."""
    if scenario is None or not scenario.can_errors:
        return 0
    simulated = getattr(bus, "inject_can_errors", None)
    if callable(simulated):
        specs = injections(scenario.can_errors, scenario.seed, 0)
        simulated(*specs)
        return len(specs)
    if not isinstance(bus, WireBus):
        raise CanErrorsNeedWire(
            "the fault scenario's can_errors need the CAN bus on ralfwire (python-can interface 'ralfwire' with a bit rate)"
            f" or the simulated rig's wire (can_bitrate with clock cosim or one-process lockstep); this run's bus is {type(bus).__name__}"
        )
    wire = bus.wire
    origin = wire.clock.now_ns() if getattr(wire.clock, "realtime", True) else 0
    specs = injections(scenario.can_errors, scenario.seed, origin)
    wire.inject_errors(*specs)
    return len(specs)
