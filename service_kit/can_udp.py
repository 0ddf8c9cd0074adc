"""A python-can bus that speaks udp_multicast without reading its own frames.

python-can's ``udp_multicast`` interface sends and receives on one socket,
and the kernel's multicast loop hands every frame a process sends straight
back to that socket (``receive_own_messages=False`` is the only value it
accepts, yet its own frames still arrive). The rig's masters read them off
the socket and throw them away: two wake-ups, two ``recvmsg`` calls and two
decodes per control tick in the controller, one or two in the plant, all on
the sample period's critical path (docs/timing.md, "The CAN bus").

:class:`LoopFreeUdpMulticastBus` is wire-compatible with ``udp_multicast``
(same group, port, TTL and python-can's own msgpack codec,
:func:`can.interfaces.udp_multicast.utils.pack_message` /
``unpack_message``), so stock tools on the same channel (``can.viewer``, a
canopen master, a cantools decoder on a plain ``udp_multicast`` bus) see and
drive the rig exactly as before. It differs in two places:

- it **sends from a socket of its own** (connected to the group, so the
  kernel picks the source address once), whose address no other sender
  shares;
- its receiving socket carries a classic BPF filter (``SO_ATTACH_FILTER``)
  that drops, in the kernel, every datagram whose source address and port
  are that sending socket's: its own frames never wake the reader. Where the
  filter cannot be attached, the same test runs on the sender address
  ``recvmsg`` returns, before any decoding (:attr:`own_frames_dropped`).

A datagram that does not begin as python-can's packed frames do
(:data:`FRAME_PREFIX`) is junk: counted (:attr:`junk_frames`) and skipped
right after ``recvmsg``, before any decoding or exception, so a junk flood
costs a reader little more than the system call
(``ralf-hil bench --only can``: ``can_junk_reject`` against the bare
``recvmsg`` floor). One that begins so and still does not decode raises
``CanOperationError`` as python-can's bus does.

It registers as the python-can interface ``ralf_udp_multicast`` (entry point
``can.interface``), and :func:`service_kit.transport.open_can_bus` uses it for
``udp_multicast`` unless ``can_udp``'s ``own_frame_filter`` is off.
"""

from __future__ import annotations

import ipaddress
import select
import socket
import struct
from typing import Any

import can
from can.interfaces.udp_multicast.utils import pack_message, unpack_message

SO_TIMESTAMPNS = 35
"""Linux: kernel receive timestamps in ns (as python-can's udp_multicast asks for)."""
SO_ATTACH_FILTER = getattr(socket, "SO_ATTACH_FILTER", 26)
SKF_NET_OFF = -0x100000
"""BPF: loads relative to the network (IP) header; plain offsets start at the UDP header."""
SO_RXQ_OVFL = 40
"""Linux: each datagram carries the socket's count of datagrams dropped for a full receive buffer."""
_MAX_DATAGRAM = 4096
FRAME_PREFIX = b"\x8b\xa9timestamp"
"""How every frame python-can's udp_multicast packs begins: a msgpack map of
11 fields whose first key is ``timestamp``
(:func:`can.interfaces.udp_multicast.utils.pack_message`)."""
JUNK_PER_READ = 64
"""Junk datagrams one read skips before it hands control back (None) to the caller."""
_ANCILLARY = socket.CMSG_SPACE(struct.calcsize("@ll")) + socket.CMSG_SPACE(4)
_TIMESPEC = struct.Struct("@ll")
_U32 = struct.Struct("@I")

# Classic BPF opcodes (linux/filter.h).
_LD_W_ABS = 0x20
_LD_H_ABS = 0x28
_JEQ_K = 0x15
_RET_K = 0x06


def _insn(code: int, jt: int, jf: int, k: int) -> bytes:
    return struct.pack("HBBI", code, jt, jf, k & 0xFFFFFFFF)


def echoing_bus(bus: can.BusABC) -> bool:
    """Whether ``bus`` hands a sender its own frames back: python-can's
    udp_multicast always does (multicast loopback); others when opened with
    ``receive_own_messages`` (:class:`LoopFreeUdpMulticastBus` never does unless asked)."""
    return type(bus).__name__ == "UdpMulticastBus" or bool(getattr(bus, "receive_own_messages", False))


def own_frame_filter(source: tuple[Any, ...], family: socket.AddressFamily) -> list[bytes]:
    """Classic BPF that drops a UDP datagram sent from ``source`` (address,
    port) and accepts every other: the UDP source port (offset 0 of a UDP
    socket's filter input), then the IP source address word by word."""
    host, port = source[0], source[1]
    packed = socket.inet_pton(family, host)
    ip_off = 12 if family == socket.AF_INET else 8  # IPv4 / IPv6 source address in the network header
    words = [struct.unpack("!I", packed[i : i + 4])[0] for i in range(0, len(packed), 4)]
    checks: list[tuple[int, int, int]] = [(_LD_H_ABS, 0, port)]
    checks += [(_LD_W_ABS, SKF_NET_OFF + ip_off + 4 * i, w) for i, w in enumerate(words)]
    prog: list[bytes] = []
    n = len(checks)
    for i, (load, off, value) in enumerate(checks):
        prog.append(_insn(load, 0, 0, off))
        # equal: on to the next check; different: jump to "accept"
        remaining = 2 * (n - 1 - i)  # instructions left before the "drop"
        prog.append(_insn(_JEQ_K, 0, remaining + 1, value))
    prog.append(_insn(_RET_K, 0, 0, 0))  # every field matched: our own frame, drop
    prog.append(_insn(_RET_K, 0, 0, 0xFFFFFFFF))  # accept
    return prog


def attach_filter(sock: socket.socket, program: list[bytes]) -> None:
    """``SO_ATTACH_FILTER`` with a classic BPF program (raises OSError where refused)."""
    import ctypes

    code = b"".join(program)
    buf = ctypes.create_string_buffer(code, len(code))
    fprog = struct.pack("HL", len(program), ctypes.addressof(buf))
    sock.setsockopt(socket.SOL_SOCKET, SO_ATTACH_FILTER, fprog)


class LoopFreeUdpMulticastBus(can.BusABC):
    """``udp_multicast`` on the wire, without reading back its own frames
    (module docstring). Arguments as python-can's ``UdpMulticastBus``:
    ``channel`` the group, ``port``, ``hop_limit`` the TTL;
    ``receive_own_messages`` hands its own frames back (the kernel's
    multicast loop delivers them; python-can's udp_multicast refuses the
    option);
    ``receive_buffer_bytes`` a larger ``SO_RCVBUF`` (best effort) for a
    reader that must keep up with a lockstep rig's back-to-back frames.
    :attr:`kernel_drops` counts the datagrams the kernel dropped because the
    receive buffer was full (as of the last datagram read), and
    :attr:`fd_frames_dropped` the CAN FD frames received on a bus opened
    without ``fd``, so a loss is never silent."""

    def __init__(
        self,
        channel: str = "239.74.163.2",
        port: int = 43113,
        hop_limit: int = 1,
        receive_own_messages: bool = False,
        fd: bool = False,
        kernel_filter: bool = True,
        receive_buffer_bytes: int = 0,
        **kwargs: Any,
    ) -> None:
        self.receive_own_messages = receive_own_messages
        """True: its own frames come back, as the multicast loop delivers them (nothing is dropped)."""
        version = ipaddress.ip_address(channel).version
        family = socket.AF_INET if version == 4 else socket.AF_INET6
        self.channel_info = f"{channel}:{port} (udp_multicast, own frames filtered)"
        self._fd = fd
        self.own_frames_dropped = 0
        """Own frames dropped after ``recvmsg`` (only where the kernel filter is not attached)."""
        self.kernel_drops = 0
        """Datagrams the kernel dropped for a full receive buffer: the socket's drop count
        (Linux ``SO_RXQ_OVFL``, as of the last datagram read) less this bus's own frames,
        each of which the own-frame filter drops and the kernel counts as a drop too."""
        self.socket_drops = 0
        """The socket's drop count as the kernel reports it (own frames filtered out included)."""
        self._frames_sent = 0
        self.fd_frames_dropped = 0
        """CAN FD frames received and dropped because the bus was opened without ``fd``."""
        self.junk_frames = 0
        """Datagrams that were not python-can frames (:data:`FRAME_PREFIX`), skipped before decoding."""
        self._rx = self._open_rx(family, channel, port)
        if receive_buffer_bytes > 0:
            self.set_receive_buffer(receive_buffer_bytes)
        try:
            self._tx = socket.socket(family, socket.SOCK_DGRAM)
            ttl = struct.pack("@I", hop_limit)
            if family == socket.AF_INET:
                self._tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
            else:
                self._tx.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS, ttl)
            self._tx.connect((channel, port))
            self._source = self._tx.getsockname()[:2]
            self.kernel_filter = False
            """True once the own-frame filter runs in the kernel."""
            if kernel_filter and not receive_own_messages:
                try:
                    attach_filter(self._rx, own_frame_filter(self._source, family))
                    self.kernel_filter = True
                except OSError:
                    pass  # dropped after recvmsg instead
        except OSError as exc:
            self._rx.close()
            raise can.CanInitializationError(f"could not open the sending socket: {exc}") from exc
        self._rx_fd = [self._rx]
        super().__init__(channel=channel, **kwargs)
        self._is_shutdown = False

    @staticmethod
    def _open_rx(family: socket.AddressFamily, group: str, port: int) -> socket.socket:
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            try:
                sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
            except OSError:
                pass  # not Linux: drops are not counted
            sock.bind(("", port))
            group_bin = socket.inet_pton(family, group)
            if family == socket.AF_INET:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, group_bin + struct.pack("@I", socket.INADDR_ANY))
            else:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_JOIN_GROUP, group_bin + struct.pack("@I", 0))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            raise can.CanInitializationError(f"could not open the receiving socket: {exc}") from exc
        return sock

    def _read(self) -> tuple[bytes, Any, float] | None:
        """One datagram that is not our own and not junk, without waiting
        (None: nothing queued, or :data:`JUNK_PER_READ` junk datagrams skipped)."""
        junk = 0
        while True:
            try:
                data, anc, _flags, sender = self._rx.recvmsg(_MAX_DATAGRAM, _ANCILLARY)
            except (BlockingIOError, InterruptedError):
                return None
            if not self.kernel_filter and not self.receive_own_messages and sender[:2] == self._source:
                self.own_frames_dropped += 1
                continue
            if not data.startswith(FRAME_PREFIX):
                self.junk_frames += 1
                junk += 1
                if junk >= JUNK_PER_READ:
                    return None
                continue
            timestamp = 0.0
            for level, kind, value in anc:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                    sec, nsec = _TIMESPEC.unpack(value)
                    timestamp = sec + nsec * 1e-9
                elif level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL:
                    self.socket_drops = _U32.unpack(value[:4])[0]
                    # A frame we sent is filtered (and counted) on its way back before any datagram
                    # queued after it: the multicast loop delivers to every local socket at once.
                    own = self._frames_sent if self.kernel_filter else 0
                    self.kernel_drops = max(0, self.socket_drops - own)
            return data, sender, timestamp

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        try:
            got = self._read()  # a frame already queued costs one system call
            if got is None and timeout != 0:
                ready, _, _ = select.select(self._rx_fd, [], [], timeout)
                got = self._read() if ready else None
        except OSError as exc:
            raise can.CanOperationError(f"failed to receive: {exc}") from exc
        if got is None:
            return None, False
        data, _, timestamp = got
        try:
            msg = unpack_message(data, replace={"timestamp": timestamp}, check=True)
        except Exception as exc:
            raise can.CanOperationError("could not unpack received message") from exc
        if msg.is_fd and not self._fd:
            self.fd_frames_dropped += 1
            return None, False
        return msg, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if msg.is_fd and not self._fd:
            raise can.CanOperationError("cannot send FD message over bus with CAN FD disabled")
        data = pack_message(msg)
        try:
            sent = self._tx.send(data)
        except OSError as exc:
            raise can.CanOperationError(f"failed to send: {exc}") from exc
        self._frames_sent += 1
        if sent < len(data):
            raise can.CanTimeoutError()

    def set_receive_buffer(self, n_bytes: int) -> None:
        """Best effort: ``SO_RCVBUF`` of the receiving socket (the kernel caps it at ``rmem_max``)."""
        try:
            self._rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, n_bytes)
        except OSError:
            pass

    def multicast_ttl(self) -> int:
        """The TTL (IPv6: hop limit) the kernel puts on every frame this bus sends."""
        if self._tx.family == socket.AF_INET:
            return int(self._tx.getsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL))
        return int(self._tx.getsockopt(socket.IPPROTO_IPV6, socket.IPV6_MULTICAST_HOPS))

    def fileno(self) -> int:
        return self._rx.fileno()

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._rx.close()
        self._tx.close()
