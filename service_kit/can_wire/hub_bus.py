"""python-can interface ``ralfhub``: a bus on the wire arbiter of
:mod:`service_kit.can_wire.hub`, from any process.

``can.Bus(interface="ralfhub", channel="/run/user/1000/ralf-.../can-wire.sock")``
connects to the arbiter's Unix socket; ``bitrate``, if given, must be the
arbiter's (it says its own on connect). :meth:`HubBus.send` hands the frame to
the arbiter and returns at once (a CAN controller's transmit buffer); the
frames every bus on the wire sent come back when their last EOF bit has
passed, stamped with that moment, in wire order: the bus's own frames only
with ``receive_own_messages``. ``tx_order`` ("fifo" or "priority"; default
the arbiter's) is what this bus offers the wire: its oldest pending frame or
its highest-priority one. Stock tools join as with any interface:
``python -m can.logger -i ralfhub -c SOCKET``, ``canopen.Network().connect(
interface="ralfhub", channel=SOCKET)``, ``cantools monitor``'s python-can
options.

Acceptance filters (``can_filters=`` or :meth:`~can.BusABC.set_filters`,
python-can's rule) go to the arbiter, which then delivers only the frames
they accept (:mod:`service_kit.can_wire.acceptance`), as a CAN controller
filters in hardware: the process is not woken for the rest. The bus checks
them again on receive (frames already on their way when the filters changed,
or more than :data:`~service_kit.can_wire.hub_protocol.MAX_FILTERS` filters:
then the arbiter is asked for every frame and the bus alone filters). A
filter that is no filter is a ``CanOperationError``.

CAN FD and error frames are refused (``CanOperationError``), as is a frame
the arbiter would not take (more than its limit of this bus's frames waiting
for the wire: refused there and counted). Packets that are not deliveries
are counted (:attr:`HubBus.junk`) and skipped; the arbiter going away is a
``CanOperationError`` on the next receive or send.
"""

from __future__ import annotations

import select
import socket
import time
from typing import Any

import can

from service_kit.can_wire import hub_protocol as proto
from service_kit.can_wire.acceptance import Filter, FilterError, compile_filters
from service_kit.can_wire.bits import frame_of_message

FILTERS_TIMEOUT_S = 5.0
"""How long setting filters waits for the arbiter to take them."""


class HubBus(can.BusABC):
    """The ``ralfhub`` interface (module docstring)."""

    def __init__(
        self,
        channel: Any = None,
        bitrate: int | None = None,
        receive_own_messages: bool = False,
        tx_order: str | None = None,
        connect_timeout: float = 5.0,
        **kwargs: Any,
    ) -> None:
        self._is_shutdown = True  # until connected: a refused bus has nothing to shut down
        if not channel:
            raise can.CanInitializationError("ralfhub needs the arbiter's socket path as its channel")
        if tx_order not in proto.TX_ORDER_CODES:
            raise can.CanInitializationError(f"tx_order {tx_order!r} is none of fifo, priority")
        self.receive_own_messages = receive_own_messages
        self.junk = 0
        """Packets from the arbiter that were not a delivery: counted and skipped."""
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        try:
            sock.settimeout(connect_timeout)
            sock.connect(str(channel))
            hello = proto.decode_hello(sock.recv(proto.MAX_PACKET))
        except OSError as exc:
            sock.close()
            raise can.CanInitializationError(f"no wire arbiter at {channel}: {exc.strerror or exc}") from None
        if hello is None:
            sock.close()
            raise can.CanInitializationError(f"{channel} is not a wire arbiter (no greeting)")
        if bitrate is not None and int(bitrate) != hello:
            sock.close()
            raise can.CanInitializationError(f"the wire at {channel} runs at {hello} bit/s, not {bitrate}")
        try:
            sock.send(proto.encode_options(receive_own_messages, tx_order))
        except OSError as exc:
            sock.close()
            raise can.CanInitializationError(f"the wire arbiter at {channel} went away: {exc.strerror or exc}") from None
        sock.setblocking(False)
        self._sock = sock
        self.bitrate = hello
        self.channel_info = f"ralfhub {channel} at {hello} bit/s (wire arbiter)"
        self.hub_filters: tuple[Filter, ...] | None = None
        """The filters the arbiter applies for this bus (None: every frame)."""
        try:
            super().__init__(channel=channel, **kwargs)  # applies can_filters (_apply_filters)
        except BaseException:
            sock.close()
            raise
        self._is_shutdown = False

    def _apply_filters(self, filters: can.typechecking.CanFilters | None) -> None:
        """python-can's hardware-filter hook: the filters go to the arbiter (module docstring)."""
        try:
            compiled = compile_filters(filters)
        except FilterError as exc:
            raise can.CanOperationError(f"ralfhub: {exc}") from None
        if compiled is not None and len(compiled) > proto.MAX_FILTERS:
            compiled = None  # more than the arbiter holds: every frame comes, recv filters them
        self._send_packet(proto.encode_filters(compiled), FILTERS_TIMEOUT_S)
        self.hub_filters = compiled

    def _send_packet(self, packet: bytes, timeout: float | None) -> None:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                self._sock.send(packet)
                return
            except BlockingIOError:
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise can.CanTimeoutError("the wire arbiter does not take the packet") from None
                select.select([], [self._sock], [], left)
            except OSError as exc:
                raise can.CanOperationError(f"the wire arbiter is gone: {exc.strerror or exc}") from None

    def fileno(self) -> int:
        return self._sock.fileno()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd or msg.is_error_frame:
            raise can.CanOperationError("ralfhub carries classical CAN data and remote frames only")
        try:
            frame_of_message(msg)
        except ValueError as exc:
            raise can.CanOperationError(f"ralfhub cannot send this frame: {exc}") from exc
        self._send_packet(proto.encode_send(msg), timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            try:
                packet = self._sock.recv(proto.MAX_PACKET)
            except (BlockingIOError, InterruptedError):
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    return None, False
                ready, _, _ = select.select([self._sock], [], [], left)
                if not ready:
                    return None, False
                continue
            except OSError as exc:
                raise can.CanOperationError(f"the wire arbiter is gone: {exc.strerror or exc}") from None
            if not packet:
                raise can.CanOperationError("the wire arbiter closed the connection")
            got = proto.decode_delivery(packet)
            if got is None:
                self.junk += 1
                continue
            if got.own and not self.receive_own_messages:
                continue
            return got.msg, False

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._sock.close()
