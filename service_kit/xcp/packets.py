"""XCP packets (ASAM MCD-1 XCP 1.x, protocol layer): command codes, error
codes, the positive and negative responses and the Ethernet frame.

A packet is what the protocol layer sees: the PID (command code, 0xFF for a
positive response, 0xFE for an error, an ODT number for a DAQ DTO) and its
fields, little-endian (the slave's byte order is INTEL). On Ethernet each
packet travels in a frame ``LEN u16 LE + CTR u16 LE + packet`` (XCP on
Ethernet); :func:`frame` builds one and :func:`split_frames` cuts a
datagram or a stream into packets.
"""

from __future__ import annotations

import struct
from enum import IntEnum
from typing import Final

__all__ = ["Cmd", "Err", "FRAME_HEADER", "FrameError", "error", "frame", "ok", "split_frames"]

PID_RES: Final = 0xFF
"""A positive response."""
PID_ERR: Final = 0xFE
"""A negative response (its second byte is the error code)."""


class Cmd(IntEnum):
    """The command codes the slave knows (XCP 1.x, table of commands)."""

    CONNECT = 0xFF
    DISCONNECT = 0xFE
    GET_STATUS = 0xFD
    SYNCH = 0xFC
    GET_COMM_MODE_INFO = 0xFB
    GET_ID = 0xFA
    SET_MTA = 0xF6
    UPLOAD = 0xF5
    SHORT_UPLOAD = 0xF4
    DOWNLOAD = 0xF0
    SHORT_DOWNLOAD = 0xED
    SET_DAQ_PTR = 0xE2
    WRITE_DAQ = 0xE1
    SET_DAQ_LIST_MODE = 0xE0
    START_STOP_DAQ_LIST = 0xDE
    START_STOP_SYNCH = 0xDD
    GET_DAQ_CLOCK = 0xDC
    GET_DAQ_PROCESSOR_INFO = 0xDA
    GET_DAQ_RESOLUTION_INFO = 0xD9
    GET_DAQ_EVENT_INFO = 0xD7
    FREE_DAQ = 0xD6
    ALLOC_DAQ = 0xD5
    ALLOC_ODT = 0xD4
    ALLOC_ODT_ENTRY = 0xD3


class Err(IntEnum):
    """XCP error codes (the second byte of a negative response)."""

    ERR_CMD_SYNCH = 0x00
    ERR_CMD_BUSY = 0x10
    ERR_DAQ_ACTIVE = 0x11
    ERR_CMD_UNKNOWN = 0x20
    ERR_CMD_SYNTAX = 0x21
    ERR_OUT_OF_RANGE = 0x22
    ERR_WRITE_PROTECTED = 0x23
    ERR_ACCESS_DENIED = 0x24
    ERR_ACCESS_LOCKED = 0x25
    ERR_SEQUENCE = 0x29
    ERR_DAQ_CONFIG = 0x2A
    ERR_MEMORY_OVERFLOW = 0x30
    ERR_GENERIC = 0x31


def ok(*fields: bytes) -> bytes:
    """A positive response: 0xFF, then the fields."""
    return bytes((PID_RES,)) + b"".join(fields)


def error(code: Err) -> bytes:
    """A negative response: 0xFE and the error code."""
    return bytes((PID_ERR, int(code)))


FRAME_HEADER: Final = struct.Struct("<HH")
"""XCP on Ethernet: LEN (the packet's length) and CTR, both u16 little-endian."""


class FrameError(ValueError):
    """Bytes that are not a whole XCP-on-Ethernet frame (a header cut short,
    a length of 0 or above the largest packet, a packet cut short)."""


def frame(packet: bytes, counter: int) -> bytes:
    """``packet`` in an XCP-on-Ethernet frame with counter ``counter`` (mod 2^16)."""
    return FRAME_HEADER.pack(len(packet), counter & 0xFFFF) + packet


def split_frames(data: bytes, max_packet: int) -> tuple[list[tuple[int, bytes]], int]:
    """The ``(ctr, packet)`` of each whole frame in ``data`` and the number of
    bytes they took; stops at the first incomplete frame (a stream's tail
    waits for more). Raises :class:`FrameError` on a length of 0 or above
    ``max_packet`` (nothing after it can be trusted)."""
    out: list[tuple[int, bytes]] = []
    pos, n = 0, len(data)
    while n - pos >= FRAME_HEADER.size:
        length, ctr = FRAME_HEADER.unpack_from(data, pos)
        if length == 0 or length > max_packet:
            raise FrameError(f"frame length {length} outside 1..{max_packet}")
        end = pos + FRAME_HEADER.size + length
        if end > n:
            break
        out.append((ctr, bytes(data[pos + FRAME_HEADER.size : end])))
        pos = end
    return out, pos
