"""What the UDP, TCP and CAN transports share: the thread, the bounded queue of
snapshots the loop hands over, and the DTO sending with its overload count.

The control loop never waits here: :meth:`Server.offer` appends to a
bounded deque (a full queue drops the sample, counted as
``snapshots_dropped``). The server's own thread serves the socket and turns
each queued snapshot into DAQ packets (:meth:`Slave.on_snapshot`); a packet
the socket does not take at once is counted as ``daq_overloads`` (XCP's
overload condition) and dropped, never retried.
"""

from __future__ import annotations

import logging
import socket
import threading
from collections import deque
from typing import Final

from service_kit.xcp.packets import frame
from service_kit.xcp.slave import Slave, Snapshot

__all__ = ["QUEUE_CAPACITY", "Server"]

log = logging.getLogger(__name__)

QUEUE_CAPACITY: Final = 8192
"""Snapshots the queue holds between two turns of the server's thread."""
POLL_S: Final = 0.005
"""How long the thread waits for a command before it looks at the queue again."""


class Server:
    """One transport serving one :class:`Slave` on a thread of its own."""

    name = "xcp"
    sock: socket.socket

    def __init__(self, slave: Slave, sock: socket.socket | None, capacity: int = QUEUE_CAPACITY) -> None:
        self.slave = slave
        self.counters = slave.counters
        if sock is not None:  # None on CAN: that transport keeps its bus
            self.sock = sock
        self.port: int = sock.getsockname()[1] if sock is not None else 0
        self._queue: deque[Snapshot] = deque()
        self._capacity = capacity
        self._stop = threading.Event()
        self._ctr = 0
        self._thread = threading.Thread(target=self._run, name=self.name, daemon=True)

    def offer(self, snapshot: Snapshot) -> None:
        """From the loop: queue one sample, or count it dropped. Never blocks."""
        if len(self._queue) >= self._capacity:
            self.counters.snapshots_dropped += 1
        else:
            self._queue.append(snapshot)

    def start(self) -> None:
        self._thread.start()

    def close(self, timeout: float = 2.0) -> None:
        """Stop the thread after it has sent what the queue held."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)
        self._close_sockets()

    def _frame(self, packet: bytes) -> bytes:
        ctr = self._ctr
        self._ctr = (ctr + 1) & 0xFFFF
        return frame(packet, ctr)

    def _run(self) -> None:
        try:
            while True:
                stopping = self._stop.is_set()
                self._serve(0.0 if self._queue else POLL_S)
                self._drain()
                if stopping:
                    break
        except Exception:  # the rig goes on without XCP
            self.counters.internal_errors += 1
            log.exception("%s server stopped", self.name)

    def _drain(self) -> None:
        queue, slave = self._queue, self.slave
        while queue:
            for dto in slave.on_snapshot(queue.popleft()):
                if self._send_dto(dto):
                    self.counters.dtos_sent += 1
                else:
                    self.counters.daq_overloads += 1

    # the transport's part
    def _serve(self, timeout: float) -> None:
        raise NotImplementedError

    def _send_dto(self, packet: bytes) -> bool:
        raise NotImplementedError

    def _close_sockets(self) -> None:
        self.sock.close()
