"""XCP on Ethernet, UDP: one datagram carries one or more frames
(``LEN u16 LE + CTR u16 LE + packet``); answers and DAQ packets go to the
address the last command came from."""

from __future__ import annotations

import select
import socket
from typing import Final

from service_kit.xcp.packets import FrameError, split_frames
from service_kit.xcp.server import QUEUE_CAPACITY, Server
from service_kit.xcp.slave import MAX_CTO, Slave

__all__ = ["UdpServer"]

MAX_DATAGRAMS: Final = 256
"""Datagrams read in one turn of the thread before it looks at the DAQ queue again."""


class UdpServer(Server):
    """Serves ``slave`` on a UDP socket bound to ``(host, port)`` (port 0: any free one)."""

    name = "xcp-udp"

    def __init__(self, slave: Slave, host: str, port: int, capacity: int = QUEUE_CAPACITY) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((host, port))
        except OSError:
            sock.close()
            raise
        sock.setblocking(False)
        super().__init__(slave, sock, capacity)
        self.master: tuple[str, int] | None = None

    def _serve(self, timeout: float) -> None:
        readable, _, _ = select.select([self.sock], [], [], timeout)
        for _ in range(MAX_DATAGRAMS if readable else 0):  # bounded: a flood must not starve the DAQ queue
            try:
                data, address = self.sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # an ICMP error from an earlier send: the master went away
                self.counters.malformed += 1
                return
            self._datagram(data, address)

    def _datagram(self, data: bytes, address: tuple[str, int]) -> None:
        try:
            packets, used = split_frames(data, MAX_CTO)
        except FrameError:
            self.counters.malformed += 1
            return
        if used != len(data) or not packets:
            self.counters.malformed += 1  # a frame cut short: dropped, the whole ones before it answered
        for _, packet in packets:
            response = self.slave.handle(packet)
            if response is not None:
                self.master = address
                self._sendto(self._frame(response), address)

    def _sendto(self, data: bytes, address: tuple[str, int]) -> bool:
        try:
            self.sock.sendto(data, address)
            return True
        except OSError:
            return False

    def _send_dto(self, packet: bytes) -> bool:
        master = self.master
        return master is not None and self._sendto(self._frame(packet), master)
