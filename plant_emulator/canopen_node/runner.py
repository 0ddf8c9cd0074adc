"""The node's I/O loop on a python-can bus: the only part with a clock and a socket."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import can

from plant_emulator.canopen_node.node import CanopenNode

log = logging.getLogger(__name__)


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
    errors are logged and counted, never raised. The bus belongs to the
    caller (open and shut it there; :func:`node_can_filters` suits it).
    ``after_send`` runs after each received frame's answer is on the bus
    (the application's work that must not delay the answer).
    """

    def send(frames: list[can.Message]) -> None:
        for frame in frames:
            try:
                bus.send(frame)
            except (can.CanError, OSError) as e:
                node.counters.tx_errors += 1
                if node.counters.tx_errors == 1 or node.counters.tx_errors % 1000 == 0:
                    log.warning("node %d: send failed (%d so far): %s", node.node_id, node.counters.tx_errors, e)

    own_ids = node.own_cob_ids
    send(node.poll(clock()))
    while not stop.is_set():
        now = clock()
        deadline = node.next_deadline()
        timeout = max_wait_s if deadline is None else min(max(deadline - now, 0.0), max_wait_s)
        try:
            msg = bus.recv(timeout)
        except (can.CanError, OSError) as e:
            node.counters.rx_errors += 1
            if node.counters.rx_errors == 1 or node.counters.rx_errors % 1000 == 0:
                log.warning("node %d: receive failed (%d so far): %s", node.node_id, node.counters.rx_errors, e)
            stop.wait(0.001)  # a broken bus must not spin the CPU
            continue
        now = clock()
        if msg is not None:
            if msg.arbitration_id in own_ids and not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame):
                # Our own frame back from the bus (udp_multicast loops every frame back to its
                # sender): counted as handle counts it, without handle's and poll's work, so the
                # node is back in recv sooner for the next SYNC (nothing in it can change a timer).
                node.count_own_echo()
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
