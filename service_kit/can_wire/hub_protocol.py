"""The wire arbiter's packets (:mod:`service_kit.can_wire.hub`): one classical
CAN frame per packet on a Unix ``SOCK_SEQPACKET`` socket, so a packet is
never split or merged and junk cannot shift the next frame.

- hub -> client, once on connect: ``HELLO`` (magic, bit rate);
- client -> hub, optionally: ``OPTIONS`` (magic, flags: bit 0 it wants its own
  frames back, bits 1-2 its transmit order: 0 the arbiter's default, 1 FIFO,
  2 priority; without it, it gets its own frames and the default order);
- client -> hub, any time: ``FILTERS`` (magic, count, then per filter its
  identifier, mask and kind: :mod:`service_kit.can_wire.acceptance`); from
  then on the hub delivers only the frames they accept (count 0: every frame,
  as without it);
- client -> hub: ``SEND`` (magic, identifier, flags, DLC, 8 data bytes);
- hub -> client: ``DELIVER`` (the frame as sent, the monotonic nanosecond of
  its last EOF bit, its python-can timestamp on ``time.time``'s axis, and
  whether it was this client's own frame).

Flags: bit 0 extended identifier, bit 1 remote frame. Anything else (wrong
size, magic, DLC above 8, an identifier out of range, unknown flags) is junk:
:func:`decode_send` returns None and the hub counts it.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import can

from service_kit.can_wire.acceptance import EITHER, EXTENDED_ONLY, Filter
from service_kit.can_wire.bits import EXTENDED_ID_MAX, STANDARD_ID_MAX

HELLO = struct.Struct("<4sI")
SEND = struct.Struct("<4sIBB8s")
DELIVER = struct.Struct("<4sIBB8sqdB")
OPTIONS = struct.Struct("<4sB")
FILTERS = struct.Struct("<4sH")
FILTER = struct.Struct("<IIB")
HELLO_MAGIC = b"RWh1"
SEND_MAGIC = b"RWs1"
DELIVER_MAGIC = b"RWd1"
OPTIONS_MAGIC = b"RWo1"
FILTERS_MAGIC = b"RWf1"
MAX_FILTERS = 64
"""Filters one client may set in the hub (a CAN controller's filter banks); a bus with more filters in software."""
EXTENDED = 1
REMOTE = 2
MAX_PACKET = 1024
"""Bytes read per packet: more than any valid packet, so an oversized one is seen whole as junk."""


def _flags(msg: can.Message) -> int:
    return (EXTENDED if msg.is_extended_id else 0) | (REMOTE if msg.is_remote_frame else 0)


def _fields(ident: int, flags: int, dlc: int, data: bytes) -> can.Message | None:
    if flags & ~(EXTENDED | REMOTE) or dlc > 8:
        return None
    extended = bool(flags & EXTENDED)
    if ident > (EXTENDED_ID_MAX if extended else STANDARD_ID_MAX):
        return None
    remote = bool(flags & REMOTE)
    return can.Message(arbitration_id=ident, is_extended_id=extended, is_remote_frame=remote, dlc=dlc, data=b"" if remote else data[:dlc], check=False)


def encode_hello(bitrate: int) -> bytes:
    return HELLO.pack(HELLO_MAGIC, bitrate)


def decode_hello(packet: bytes) -> int | None:
    if len(packet) != HELLO.size:
        return None
    magic, bitrate = HELLO.unpack(packet)
    return int(bitrate) if magic == HELLO_MAGIC else None


TX_ORDER_CODES = {None: 0, "fifo": 1, "priority": 2}


def encode_options(receive_own: bool, tx_order: str | None = None) -> bytes:
    return OPTIONS.pack(OPTIONS_MAGIC, (1 if receive_own else 0) | TX_ORDER_CODES[tx_order] << 1)


def decode_options(packet: bytes) -> tuple[bool, str | None] | None:
    """Whether the client wants its own frames and its transmit order (None: the arbiter's),
    or None when ``packet`` is no ``OPTIONS``."""
    if len(packet) != OPTIONS.size:
        return None
    magic, flags = OPTIONS.unpack(packet)
    orders = {code: order for order, code in TX_ORDER_CODES.items()}
    if magic != OPTIONS_MAGIC or flags >> 1 not in orders:
        return None
    return bool(flags & 1), orders[flags >> 1]


def encode_filters(filters: tuple[Filter, ...] | None) -> bytes:
    """``FILTERS`` for compiled filters (None: every frame); ValueError for more than :data:`MAX_FILTERS`."""
    filters = filters or ()
    if len(filters) > MAX_FILTERS:
        raise ValueError(f"{len(filters)} filters: the arbiter holds at most {MAX_FILTERS}")
    return FILTERS.pack(FILTERS_MAGIC, len(filters)) + b"".join(FILTER.pack(*f) for f in filters)


def decode_filters(packet: bytes) -> tuple[tuple[Filter, ...] | None] | None:
    """``(filters,)`` (``(None,)``: every frame), or None when ``packet`` is no valid ``FILTERS``."""
    if len(packet) < FILTERS.size:
        return None
    magic, count = FILTERS.unpack_from(packet)
    if magic != FILTERS_MAGIC or count > MAX_FILTERS or len(packet) != FILTERS.size + count * FILTER.size:
        return None
    out: list[Filter] = []
    for i in range(count):
        can_id, mask, kind = FILTER.unpack_from(packet, FILTERS.size + i * FILTER.size)
        if can_id > EXTENDED_ID_MAX or mask > EXTENDED_ID_MAX or not EITHER <= kind <= EXTENDED_ONLY:
            return None
        out.append((can_id, mask, kind))
    return (tuple(out) or None,)


def encode_send(msg: can.Message) -> bytes:
    data = bytes(msg.data or b"")
    return SEND.pack(SEND_MAGIC, msg.arbitration_id, _flags(msg), msg.dlc, data.ljust(8, b"\0")[:8])


def decode_send(packet: bytes) -> can.Message | None:
    """The frame a client sent, or None for junk."""
    if len(packet) != SEND.size:
        return None
    magic, ident, flags, dlc, data = SEND.unpack(packet)
    if magic != SEND_MAGIC:
        return None
    return _fields(ident, flags, dlc, data)


@dataclass(frozen=True)
class Delivered:
    msg: can.Message
    """Stamped with the time of its last EOF bit (``time.time``'s axis)."""
    last_bit_ns: int
    """The same moment on ``time.monotonic_ns`` of the hub's host."""
    own: bool


def encode_delivery(msg: can.Message, last_bit_ns: int, own: bool) -> bytes:
    data = bytes(msg.data or b"")
    return DELIVER.pack(DELIVER_MAGIC, msg.arbitration_id, _flags(msg), msg.dlc, data.ljust(8, b"\0")[:8], last_bit_ns, msg.timestamp, 1 if own else 0)


def decode_delivery(packet: bytes) -> Delivered | None:
    if len(packet) != DELIVER.size:
        return None
    magic, ident, flags, dlc, data, last_bit_ns, stamp, own = DELIVER.unpack(packet)
    if magic != DELIVER_MAGIC:
        return None
    msg = _fields(ident, flags, dlc, data)
    if msg is None:
        return None
    msg.timestamp = stamp
    return Delivered(msg, int(last_bit_ns), bool(own))
