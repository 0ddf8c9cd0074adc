"""One turn of the node's I/O loop without waiting: for a bus on a clock its
caller moves (``ralfwire`` with a :class:`~service_kit.can_wire.wire_bus.ManualWireClock`),
where :func:`~plant_emulator.canopen_node.runner.run_node`'s waits would
stall the clock. The same steps as one turn of ``run_node``: every frame
waiting is handled, the bus's CAN error state reported (:mod:`.can_state`),
the timers polled, and the answers sent (a refused send counted in the
node's ``tx_errors``, as there)."""

from __future__ import annotations

import can

from plant_emulator.canopen_node.node import CanopenNode
from service_kit.can_wire.wire_errors import error_state_reader


def serve_once(bus: can.BusABC, node: CanopenNode, now: float) -> None:
    """Serve ``node`` on ``bus`` at ``now`` (seconds, the node's clock) once (module docstring)."""
    frames: list[can.Message] = []
    while (msg := bus.recv(0)) is not None:
        frames += node.handle(msg, now)
    read_state = error_state_reader(bus)
    if read_state is not None:
        node.can_error_state(read_state())
    for frame in frames + node.poll(now):
        try:
            bus.send(frame)
        except (can.CanError, OSError):
            node.counters.tx_errors += 1
