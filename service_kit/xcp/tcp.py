"""XCP on Ethernet, TCP: a stream of frames (``LEN u16 LE + CTR u16 LE +
packet``) from one master at a time. A frame whose length is 0 or above
the largest command leaves nothing after it readable: the connection is
closed (counted as ``malformed``). A second master is refused (its
connection closed at once) while one is connected."""

from __future__ import annotations

import select
import socket
from typing import Final

from service_kit.xcp.packets import FrameError, split_frames
from service_kit.xcp.server import QUEUE_CAPACITY, Server
from service_kit.xcp.slave import MAX_CTO, Slave

__all__ = ["TcpServer"]

SEND_TIMEOUT_S: Final = 0.5
"""A DAQ packet or an answer the master's socket does not take within this is an overload; the connection closes."""
MAX_BUFFER: Final = 1 << 16
"""Unread bytes kept from the master."""


class TcpServer(Server):
    """Serves ``slave`` on a TCP socket listening on ``(host, port)`` (port 0: any free one)."""

    name = "xcp-tcp"

    def __init__(self, slave: Slave, host: str, port: int, capacity: int = QUEUE_CAPACITY) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(2)
        except OSError:
            sock.close()
            raise
        sock.setblocking(False)
        super().__init__(slave, sock, capacity)
        self.client: socket.socket | None = None
        self._buffer = b""
        self.refused_connections = 0

    def _serve(self, timeout: float) -> None:
        watched = [self.sock] if self.client is None else [self.sock, self.client]
        readable, _, _ = select.select(watched, [], [], timeout)
        client = self.client
        if client is not None and client in readable:  # first: a master that left frees its place for the next
            try:
                data = client.recv(65536)
            except OSError:
                data = b""
            if not data:
                self._drop_client()
            else:
                self._stream(data)
        if self.sock in readable:
            self._accept()

    def _accept(self) -> None:
        try:
            conn, _ = self.sock.accept()
        except OSError:
            return
        if self.client is not None:
            self.refused_connections += 1
            self.counters.masters_refused += 1
            conn.close()
            return
        conn.setblocking(True)
        conn.settimeout(SEND_TIMEOUT_S)
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client, self._buffer = conn, b""

    def _stream(self, data: bytes) -> None:
        buffer = self._buffer + data
        try:
            packets, used = split_frames(buffer, MAX_CTO)
        except FrameError:
            self.counters.malformed += 1
            self._drop_client()
            return
        self._buffer = buffer[used:]
        if len(self._buffer) > MAX_BUFFER:
            self.counters.malformed += 1
            self._drop_client()
            return
        for _, packet in packets:
            response = self.slave.handle(packet)
            if response is not None and not self._send(self._frame(response)):
                return

    def _send(self, data: bytes) -> bool:
        client = self.client
        if client is None:
            return False
        try:
            client.sendall(data)
            return True
        except OSError:  # a timeout included: the stream can no longer be trusted
            self._drop_client()
            return False

    def _send_dto(self, packet: bytes) -> bool:
        return self._send(self._frame(packet))

    def _drop_client(self) -> None:
        if self.client is not None:
            self.client.close()
            if self.slave.connected:
                self.counters.sessions_lost += 1
        self.client, self._buffer = None, b""
        self.slave.reset()  # the session ends with its connection

    def _close_sockets(self) -> None:
        if self.client is not None:
            self.client.close()
            self.client = None
        self.sock.close()
