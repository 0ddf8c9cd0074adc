"""A classical CAN frame's exact bit sequence on the wire (ISO 11898-1).

:func:`frame_bits` lays out a data or remote frame, standard (11-bit) or
extended (29-bit) identifier, bit by bit as the bus carries it (0 =
dominant, 1 = recessive):

- standard: SOF, ID[10:0], RTR, IDE (dominant), r0, DLC[3:0], data, CRC;
- extended: SOF, ID[28:18], SRR (recessive), IDE (recessive), ID[17:0],
  RTR, r1, r0, DLC[3:0], data, CRC;

then the CRC delimiter, the ACK slot (dominant once a receiver
acknowledges), the ACK delimiter, the end of frame (7 recessive bits) and
the intermission (3 recessive bits) that must pass before the next frame
may start.

The CRC-15 (generator x^15+x^14+x^10+x^8+x^7+x^4+x^3+1, 0x4599, initial
value 0) runs over SOF..data before stuffing (ISO 11898-1, "CRC field").
Bit stuffing (ISO 11898-1, "bit stuffing") inserts a bit of opposite value
after every 5 consecutive equal bits of SOF..CRC sequence, the stuff bits
themselves counting towards the next run; it is computed from the frame's
actual bits, so :attr:`FrameBits.n_stuff` is this frame's count, not a
worst-case estimate. A fifth equal bit at the very end of the CRC sequence
is followed by a stuff bit too (the receiver expects it before the CRC
delimiter).

Everything here is pure: same frame in, same bits out.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import can

CRC15_POLY = 0x4599
"""CRC-15/CAN generator polynomial without its x^15 term (ISO 11898-1)."""
STANDARD_ID_MAX = 0x7FF
EXTENDED_ID_MAX = 0x1FFFFFFF
EOF_BITS = 7
IFS_BITS = 3
"""Intermission: 3 recessive bits after EOF before the bus is free."""
TAIL_BITS = 1 + 1 + 1 + EOF_BITS
"""CRC delimiter, ACK slot, ACK delimiter, EOF: never stuffed."""


def crc15(bits: Iterable[int]) -> int:
    """CRC-15/CAN of a bit sequence, most significant (first sent) bit first
    (ISO 11898-1's shift-register description: ``CRC_NXT = NXTBIT xor
    CRC_RG(14)``, shift left, xor 0x4599 when ``CRC_NXT``)."""
    crc = 0
    for bit in bits:
        feedback = (bit & 1) ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if feedback:
            crc ^= CRC15_POLY
    return crc


def stuff(bits: Sequence[int]) -> tuple[list[int], list[int]]:
    """``bits`` with a complementary stuff bit after every 5 consecutive equal
    bits (stuff bits included in the count). Returns the stuffed bits and the
    indices of the stuff bits in them."""
    out: list[int] = []
    positions: list[int] = []
    run_value = -1
    run = 0
    for bit in bits:
        out.append(bit)
        if bit == run_value:
            run += 1
        else:
            run_value, run = bit, 1
        if run == 5:
            stuff_bit = 1 - bit
            positions.append(len(out))
            out.append(stuff_bit)
            run_value, run = stuff_bit, 1
    return out, positions


def _bits_of(value: int, width: int) -> list[int]:
    return [(value >> (width - 1 - i)) & 1 for i in range(width)]


@dataclass(frozen=True)
class FrameBits:
    """One classical CAN frame as the bus carries it."""

    arbitration_id: int
    extended: bool
    remote: bool
    dlc: int
    data: bytes
    bits: tuple[int, ...]
    """SOF .. end of intermission, stuffed (0 dominant, 1 recessive)."""
    stuff_positions: tuple[int, ...]
    """Indices in :attr:`bits` of the stuff bits."""
    crc: int
    """The CRC-15 sequence sent."""
    unstuffed: tuple[int, ...]
    """SOF .. CRC sequence before stuffing (what the CRC and arbitration see)."""

    @property
    def n_stuff(self) -> int:
        return len(self.stuff_positions)

    @property
    def n_bits(self) -> int:
        """Bits the frame occupies the bus for, intermission included."""
        return len(self.bits)

    @property
    def n_bits_to_eof(self) -> int:
        """SOF .. last EOF bit (no intermission)."""
        return len(self.bits) - IFS_BITS

    @property
    def ack_slot_index(self) -> int:
        """Index in :attr:`bits` of the ACK slot."""
        return self.n_bits_to_eof - EOF_BITS - 2

    @property
    def ack_delimiter_index(self) -> int:
        return self.ack_slot_index + 1

    @property
    def arbitration_key(self) -> tuple[int, ...]:
        """The arbitration field as sent (unstuffed; both contenders stuff
        identically up to the first bit where they differ): ID[10:0], RTR,
        IDE for a standard frame; ID[28:18], SRR, IDE, ID[17:0], RTR for an
        extended one. The lower tuple wins bitwise arbitration (a dominant 0
        overwrites a recessive 1): a lower identifier wins, a data frame
        beats a remote frame of the same identifier, and a standard frame
        beats an extended frame of the same base identifier (its RTR or IDE
        is dominant where the extended frame sends SRR and IDE recessive)."""
        end = 33 if self.extended else 14
        return self.unstuffed[1:end]


def frame_bits(
    arbitration_id: int,
    data: bytes | bytearray | Sequence[int] = b"",
    *,
    extended: bool = False,
    remote: bool = False,
    dlc: int | None = None,
    acked: bool = True,
) -> FrameBits:
    """The frame's bits (module docstring). ``dlc`` defaults to
    ``len(data)``; a remote frame carries no data and any DLC 0..15 (the
    length it requests); a data frame with 8 bytes may carry DLC 9..15
    (still 8 bytes, ISO 11898-1). ``acked=False`` leaves the ACK slot
    recessive (nobody acknowledged). Raises ValueError on a frame classical
    CAN cannot carry."""
    payload = bytes(data)
    id_max = EXTENDED_ID_MAX if extended else STANDARD_ID_MAX
    if not 0 <= arbitration_id <= id_max:
        raise ValueError(f"identifier 0x{arbitration_id:X} out of range for a {'29' if extended else '11'}-bit frame")
    if len(payload) > 8:
        raise ValueError(f"classical CAN carries at most 8 data bytes, got {len(payload)}")
    if remote and payload:
        raise ValueError("a remote frame carries no data")
    if dlc is None:
        dlc = len(payload)
    if not 0 <= dlc <= 15:
        raise ValueError(f"DLC must be 0..15, got {dlc}")
    if not remote and min(dlc, 8) != len(payload):
        raise ValueError(f"DLC {dlc} does not match {len(payload)} data bytes")
    head: list[int] = [0]  # SOF
    rtr = 1 if remote else 0
    if extended:
        head += _bits_of(arbitration_id >> 18, 11)
        head += [1, 1]  # SRR, IDE
        head += _bits_of(arbitration_id & 0x3FFFF, 18)
        head += [rtr, 0, 0]  # RTR, r1, r0
    else:
        head += _bits_of(arbitration_id, 11)
        head += [rtr, 0, 0]  # RTR, IDE, r0
    head += _bits_of(dlc, 4)
    for byte in payload:
        head += _bits_of(byte, 8)
    crc = crc15(head)
    unstuffed = head + _bits_of(crc, 15)
    stuffed, positions = stuff(unstuffed)
    tail = [1, 0 if acked else 1, 1] + [1] * EOF_BITS + [1] * IFS_BITS
    return FrameBits(
        arbitration_id=arbitration_id,
        extended=extended,
        remote=remote,
        dlc=dlc,
        data=payload,
        bits=tuple(stuffed + tail),
        stuff_positions=tuple(positions),
        crc=crc,
        unstuffed=tuple(unstuffed),
    )


def frame_of_message(msg: can.Message) -> FrameBits:
    """:func:`frame_bits` of a python-can message (its id, ``is_extended_id``,
    ``is_remote_frame``, ``dlc``, ``data``). Refuses (ValueError) CAN FD and
    error frames: they are not classical CAN data or remote frames."""
    if msg.is_fd:
        raise ValueError("CAN FD frames are not modelled")
    if msg.is_error_frame:
        raise ValueError("an error frame has no frame layout of its own")
    if msg.is_remote_frame:
        return frame_bits(msg.arbitration_id, extended=msg.is_extended_id, remote=True, dlc=msg.dlc)
    data = bytes(msg.data)
    return frame_bits(msg.arbitration_id, data, extended=msg.is_extended_id, dlc=msg.dlc if msg.dlc > 8 else len(data))
