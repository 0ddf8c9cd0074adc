"""What rejecting one junk datagram on the CAN group costs a reader
(``ralf-hil bench --only can``: ``can_junk_reject`` and its floors).

A junk flood on the rig's udp_multicast group reaches every reader of it,
the controller's link and the plant's node, which must read each datagram
to find it is not a frame. Blocks of datagrams are sent to four receivers
on private ports of the loopback, then each receiver drains its block and
the time per datagram is one sample; the receivers' blocks are interleaved,
so every figure and its floor see the same machine state:

* ``udp_recv_floor``: a bare non-blocking socket's ``recvmsg`` of each
  junk datagram (what any reader pays at least);
* ``can_junk_reject``: the rig's bus (:class:`service_kit.can_udp.LoopFreeUdpMulticastBus`)
  skipping junk before decoding (counted in ``junk_frames``);
* ``can_junk_reject (python-can stock bus)``: python-can's ``udp_multicast``
  bus, which raises ``CanOperationError`` for each one (the caller catches
  and counts it);
* ``can_junk_reject (controller link)``: the same through the controller's
  :class:`controller.plant_link.PlantLink` (its ``poll``, once per tick,
  with its counting: what the loop pays);
* ``can_frame_read``: the rig's bus reading and decoding real frames.
"""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from typing import Any

import can
from can.interfaces.udp_multicast.utils import pack_message

from service_kit.can_udp import LoopFreeUdpMulticastBus

JUNK = b"\xc1 not a CAN frame, 32 bytes long"
"""A junk datagram (of the size of a short forged payload)."""
BLOCK = 200
"""Datagrams per block: each block is drained in one go, its time per datagram one sample."""
RECEIVE_BUFFER = 4 << 20
FLOOR = "udp_recv_floor"
JUNK_REJECT = "can_junk_reject"
STOCK_JUNK_REJECT = "can_junk_reject (python-can stock bus)"
LINK_JUNK_REJECT = "can_junk_reject (controller link)"
FRAME_READ = "can_frame_read"


def _plain_socket(group: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
    sock.bind(("", port))
    sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, socket.inet_aton(group) + socket.inet_aton("0.0.0.0"))
    sock.setblocking(False)
    return sock


def _drain_socket(sock: socket.socket) -> int:
    n = 0
    while True:
        try:
            sock.recvmsg(4096, 256)
        except BlockingIOError:
            return n
        n += 1


def _drain_bus(bus: can.BusABC) -> int:
    """Datagrams handled until the bus has nothing left: frames read, junk skipped (``junk_frames``) or raised."""
    n = 0
    while True:
        skipped = getattr(bus, "junk_frames", 0)
        try:
            msg = bus.recv(0)
        except can.CanOperationError:
            n += 1
            continue
        now = getattr(bus, "junk_frames", 0)
        n += (msg is not None) + now - skipped
        if msg is None and now == skipped:
            return n


def _drain_link(link: Any) -> int:
    """Datagrams the controller's link took in (counted and dropped) until it has nothing left."""
    n = 0
    while True:
        before = link.counters.rx_errors + link.counters.junk_frames
        link.poll(0.0)
        link.take_conflicts()  # copies the bus's junk count
        got = link.counters.rx_errors + link.counters.junk_frames - before
        if not got:
            return n
        n += got


def measure(group: str, ports: Sequence[int], blocks: int) -> dict[str, list[float]]:
    """Seconds per datagram, one sample per block, for each receiver (module
    docstring); ``ports``: five free udp ports of ``group``, one per receiver."""
    if len(ports) != 5:
        raise ValueError(f"five ports, one per receiver, got {len(ports)}")
    frame = pack_message(can.Message(arbitration_id=0x181, data=bytes(8), is_extended_id=False))
    from controller.plant_link import PlantLink

    samples: dict[str, list[float]] = {FLOOR: [], JUNK_REJECT: [], STOCK_JUNK_REJECT: [], LINK_JUNK_REJECT: [], FRAME_READ: []}
    with ExitStack() as stack:
        sender = stack.enter_context(socket.socket(socket.AF_INET, socket.SOCK_DGRAM))
        sender.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        floor_sock = stack.enter_context(_plain_socket(group, ports[0]))
        rig_bus = LoopFreeUdpMulticastBus(channel=group, port=ports[1], hop_limit=0, receive_buffer_bytes=RECEIVE_BUFFER)
        stack.callback(rig_bus.shutdown)
        stock = can.Bus(interface="udp_multicast", channel=group, port=ports[2], hop_limit=0)
        stack.callback(stock.shutdown)
        with socket.fromfd(stock.fileno(), socket.AF_INET, socket.SOCK_DGRAM) as same:  # a duplicate of its receiving socket
            same.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
        frame_bus = LoopFreeUdpMulticastBus(channel=group, port=ports[3], hop_limit=0, receive_buffer_bytes=RECEIVE_BUFFER)
        stack.callback(frame_bus.shutdown)
        link_bus = LoopFreeUdpMulticastBus(channel=group, port=ports[4], hop_limit=0, receive_buffer_bytes=RECEIVE_BUFFER)
        stack.callback(link_bus.shutdown)
        link = PlantLink(link_bus, 1)
        logging.getLogger("controller.plant_link").disabled = True  # its rate-limited lines are not what is measured
        stack.callback(setattr, logging.getLogger("controller.plant_link"), "disabled", False)
        arms: list[tuple[str, int, bytes, Callable[[], int]]] = [
            (FLOOR, ports[0], JUNK, lambda: _drain_socket(floor_sock)),
            (JUNK_REJECT, ports[1], JUNK, lambda: _drain_bus(rig_bus)),
            (STOCK_JUNK_REJECT, ports[2], JUNK, lambda: _drain_bus(stock)),
            (LINK_JUNK_REJECT, ports[4], JUNK, lambda: _drain_link(link)),
            (FRAME_READ, ports[3], frame, lambda: _drain_bus(frame_bus)),
        ]
        for _, _, _, drain in arms:
            drain()
        for k in range(blocks):
            for name, port, payload, drain in arms[k % len(arms) :] + arms[: k % len(arms)]:
                for _ in range(BLOCK):
                    sender.sendto(payload, (group, port))
                start = time.perf_counter()
                handled = drain()
                spent = time.perf_counter() - start
                if handled:
                    samples[name].append(spent / handled)
    return samples


def rows(samples: dict[str, list[float]], summarize: Callable[[list[float]], dict[str, Any]], latency: Callable[..., dict[str, Any]]) -> dict[str, Any]:
    """The item's rows: each receiver's time per datagram against the bare ``recvmsg`` floor."""
    floor = summarize(samples[FLOOR])
    out = {FLOOR: latency(floor)}
    for name in (JUNK_REJECT, STOCK_JUNK_REJECT, LINK_JUNK_REJECT, FRAME_READ):
        out[name] = latency(summarize(samples[name]), FLOOR, floor, note=f"time per datagram, drained in blocks of {BLOCK}")
    return out
