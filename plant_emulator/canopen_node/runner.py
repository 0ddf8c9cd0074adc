"""The node's I/O loop on a python-can bus: the only part with a clock and a socket."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Final

import can

from plant_emulator.canopen_node.can_state import error_state_reader
from plant_emulator.canopen_node.node import CanopenNode
from service_kit.can_udp import echoing_bus

log = logging.getLogger(__name__)

RX_ERROR_STREAK_PAUSE: Final[int] = 256
"""Receive errors in a row, with no frame or timeout between them, after which the loop waits 1 ms
(a bus that fails every call, e.g. a closed socket, must not spin the CPU); junk datagrams from a
flood are read back to back at full speed, each counted."""


def _send(bus: can.BusABC, node: CanopenNode, frames: list[can.Message]) -> None:
    """Send each frame; failures are counted and logged (the first and every 1000th), never raised."""
    for frame in frames:
        try:
            bus.send(frame)
        except (can.CanError, OSError) as e:
            node.counters.tx_errors += 1
            if node.counters.tx_errors == 1 or node.counters.tx_errors % 1000 == 0:
                log.warning("node %d: send failed (%d so far): %s", node.node_id, node.counters.tx_errors, e)


def run_node(
    bus: can.BusABC,
    node: CanopenNode,
    stop: threading.Event,
    clock: Callable[[], float] = time.monotonic,
    *,
    max_wait_s: float = 0.02,
    after_send: Callable[[], None] | None = None,
) -> None:
    """Serve ``node`` on ``bus`` until ``stop`` is set (returns within ``max_wait_s``).

    Receives with a timeout bounded by the node's next deadline, so the
    heartbeat and watchdog run on time; every received frame is handled and
    answered at once (SYNC -> TPDO latency is one :meth:`CanopenNode.exchange`
    call: ``handle`` and ``poll`` in one). Send
    errors are logged and counted, never raised; receive errors (an
    undecodable udp_multicast datagram) are counted and the next frame read
    at once. The bus's own loss counters (``kernel_drops``,
    ``fd_frames_dropped``, ``junk_frames`` of :class:`service_kit.can_udp.LoopFreeUdpMulticastBus`)
    are copied into the node's counters, so health reports them. The bus
    belongs to the caller (open and shut it there; :func:`node_can_filters`
    suits it). ``after_send`` runs after each received frame's answer is on
    the bus (the application's work that must not delay the answer).
    On a bus that tells its CAN error state (``ralfwire``), the node reads it
    before each wait and reports it by EMCY (:mod:`.can_state`).
    """

    def send(frames: list[can.Message]) -> None:
        _send(bus, node, frames)

    own_ids = node.own_cob_ids
    node.expect_echoes(echoing_bus(bus))
    counted_bus = bus if hasattr(bus, "kernel_drops") and hasattr(bus, "fd_frames_dropped") else None
    counters = node.counters
    streak = 0
    can_state = error_state_reader(bus)  # None on a bus that cannot tell its error state
    send(node.poll(clock()))
    while not stop.is_set():
        if can_state is not None:
            node.can_error_state(can_state())
        now = clock()
        deadline = node.next_deadline()
        timeout = max_wait_s if deadline is None else min(max(deadline - now, 0.0), max_wait_s)
        try:
            msg = bus.recv(timeout)
        except (can.CanError, OSError) as e:
            counters.rx_errors += 1
            if counters.rx_errors == 1 or counters.rx_errors % 1000 == 0:
                log.warning("node %d: receive failed (%d so far): %s", node.node_id, counters.rx_errors, e)
            streak += 1
            if streak >= RX_ERROR_STREAK_PAUSE:
                streak = 0
                stop.wait(0.001)  # a broken bus must not spin the CPU
            if counted_bus is not None:
                counters.kernel_drops = int(counted_bus.kernel_drops)
                counters.junk_frames = int(getattr(counted_bus, "junk_frames", 0))
            now = clock()
            if deadline is not None and now >= deadline:
                send(node.poll(now))  # the heartbeat and the watchdog stay on time under a flood
            continue
        streak = 0
        now = clock()
        if counted_bus is not None:
            counters.kernel_drops = int(counted_bus.kernel_drops)
            counters.fd_frames_dropped = int(counted_bus.fd_frames_dropped)
            counters.junk_frames = int(getattr(counted_bus, "junk_frames", 0))
        if msg is not None:
            if msg.arbitration_id in own_ids and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
                # A frame on our own COB-IDs: our echo (udp_multicast loops frames back to their
                # sender) or another node using our identifiers (answered with an EMCY). Without
                # handle's and poll's work, so the node is back in recv sooner for the next SYNC.
                send([f.to_message() for f in node.own_cob_frame(msg.arbitration_id, msg.data, now)])
                if deadline is None or now < deadline:
                    continue
            elif msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame:
                send(node.handle(msg, now))
                if after_send is not None:
                    after_send()
            else:  # a standard data frame: handle + poll in one call (the same frames, in the same order)
                send([f.to_message() for f in node.exchange(msg.arbitration_id, msg.data, now)])
                if after_send is not None:
                    after_send()
                continue
        send(node.poll(now))
