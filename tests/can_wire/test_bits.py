"""The frame's bits against references: sigrok-cli's CAN decoder, the
CRC-15/CAN catalogue check value, Davis et al.'s worst-case length, a
brute-force search of every payload, and a frame worked by hand and
decoded by sigrok-cli (0x181, 8 bytes 11..88)."""

from __future__ import annotations

from pathlib import Path

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire.bits import IFS_BITS, crc15, frame_bits, frame_of_message, stuff
from service_kit.can_wire.timing import STANDARD_BITRATES, bit_time_ns, wire_time_ns, worst_case_bits
from service_kit.can_wire.worst_case import longest_frame, longest_payload, shortest_frame
from tests.can_wire.sigrok import decode, needs_sigrok

HAND_CHECKED = bytes([0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88])


def test_hand_checked_frame() -> None:
    frame = frame_bits(0x181, HAND_CHECKED)
    assert frame.n_bits == 115  # SOF..IFS
    assert frame.n_stuff == 4
    assert frame.crc == 0x0B7F
    assert frame.n_bits_to_eof == 115 - IFS_BITS
    assert wire_time_ns(frame.n_bits, 1_000_000) == 115_000


def test_crc15_catalogue_check_value() -> None:
    """CRC-15/CAN (width 15, poly 0x4599, init 0, no reflection, xorout 0) of
    the ASCII bytes "123456789" is 0x059E in the CRC catalogue."""
    bits = [(byte >> (7 - i)) & 1 for byte in b"123456789" for i in range(8)]
    assert crc15(bits) == 0x059E


def test_bit_times() -> None:
    assert [bit_time_ns(r) for r in STANDARD_BITRATES] == [8000, 4000, 2000, 1000]
    with pytest.raises(ValueError):
        bit_time_ns(300_000)


def _unstuff_and_check_runs(frame_bits_: tuple[int, ...], positions: tuple[int, ...], n_stuffable: int) -> list[int]:
    """Removes the stuff bits, checking that each one is the complement of
    the 5 equal bits before it and that no 6 equal bits remain."""
    stuffed_len = n_stuffable + len(positions)
    region = frame_bits_[:stuffed_len]
    for p in positions:
        assert len(set(region[p - 5 : p])) == 1 and region[p] != region[p - 1]
    for i in range(len(region) - 5):
        assert len(set(region[i : i + 6])) == 2
    return [b for i, b in enumerate(region) if i not in set(positions)]


@settings(max_examples=300, deadline=None)
@given(
    extended=st.booleans(),
    ident=st.integers(0, 0x1FFFFFFF),
    data=st.binary(max_size=8),
    remote=st.booleans(),
)
def test_any_frame_within_davis_bound(extended: bool, ident: int, data: bytes, remote: bool) -> None:
    if not extended:
        ident &= 0x7FF
    if remote:
        frame = frame_bits(ident, extended=extended, remote=True, dlc=len(data))
        n_data = 0
    else:
        frame = frame_bits(ident, data, extended=extended)
        n_data = len(data)
    g = 54 if extended else 34
    assert frame.n_bits <= worst_case_bits(n_data, extended=extended)
    assert frame.n_bits == g + 8 * n_data + 13 + frame.n_stuff
    unstuffed = _unstuff_and_check_runs(frame.bits, frame.stuff_positions, g + 8 * n_data)
    assert tuple(unstuffed) == frame.unstuffed
    assert frame.bits[len(unstuffed) + frame.n_stuff :] == (1, 0, 1) + (1,) * 10


def test_stuffing_counts_stuff_bits_in_the_next_run() -> None:
    stuffed, positions = stuff([0] * 5 + [1] * 4 + [0])
    # 00000 [1] 1111 [0] 0: the stuff bit 1 starts the run of ones
    assert stuffed == [0, 0, 0, 0, 0, 1, 1, 1, 1, 1, 0, 0]
    assert positions == [5, 10]


@pytest.mark.parametrize("ident", [0x000, 0x181, 0x7FF])
def test_longest_payload_matches_brute_force(ident: int) -> None:
    """Every one of the 256 one-byte payloads against the dynamic programme."""
    lengths = [frame_bits(ident, bytes([b])).n_bits for b in range(256)]
    worst = max(lengths)
    assert longest_frame(ident, 1).n_bits == worst
    assert shortest_frame(ident, 1).n_bits == min(lengths)
    assert worst <= worst_case_bits(1)


def test_longest_two_byte_payload_matches_brute_force() -> None:
    lengths = [frame_bits(0x080, i.to_bytes(2, "big")).n_bits for i in range(1 << 16)]
    assert longest_frame(0x080, 2).n_bits == max(lengths)
    assert shortest_frame(0x080, 2).n_bits == min(lengths)


@pytest.mark.parametrize("extended", [False, True])
def test_longest_frames_stay_within_davis_bound(extended: bool) -> None:
    """The exact longest frames come within a few bits of Davis et al.'s
    C_m but never above: its perfect 00000 1111 0000 ... pattern cannot pass
    a frame's fixed IDE/SRR/r0 bits."""
    ident = 0x1FFFFFFF if extended else 0x000
    for n in (0, 4, 8):
        frame = longest_frame(ident, n, extended=extended)
        bound = worst_case_bits(n, extended=extended)
        assert bound - 6 <= frame.n_bits <= bound


@settings(max_examples=100, deadline=None)
@given(data=st.binary(min_size=8, max_size=8))
def test_no_payload_beats_the_longest(data: bytes) -> None:
    assert frame_bits(0x181, data).n_bits <= _LONGEST_0x181


_LONGEST_0x181 = frame_bits(0x181, longest_payload(0x181, 8)).n_bits


def test_refusals() -> None:
    with pytest.raises(ValueError, match="out of range"):
        frame_bits(0x800, b"")
    with pytest.raises(ValueError, match="at most 8"):
        frame_bits(1, bytes(9))
    with pytest.raises(ValueError, match="no data"):
        frame_bits(1, b"\x01", remote=True)
    with pytest.raises(ValueError, match="FD"):
        frame_of_message(can.Message(arbitration_id=1, data=bytes(12), is_fd=True))
    with pytest.raises(ValueError, match="error frame"):
        frame_of_message(can.Message(is_error_frame=True))


def test_message_round_trip() -> None:
    msg = can.Message(arbitration_id=0x181, data=HAND_CHECKED, is_extended_id=False)
    assert frame_of_message(msg) == frame_bits(0x181, HAND_CHECKED)
    rtr = can.Message(arbitration_id=0x701, is_remote_frame=True, dlc=1, is_extended_id=False)
    assert frame_of_message(rtr).remote and frame_of_message(rtr).dlc == 1


# --- sigrok-cli's CAN decoder -------------------------------------------------

SIGROK_FRAMES = [
    (0x181, HAND_CHECKED, False, False),
    (0x080, b"", False, False),
    (0x080, b"\x01", False, False),
    (0x201, b"\x00\x00\x00\x00", False, False),
    (0x000, longest_payload(0x000, 8), False, False),
    (0x7EF, bytes(8), False, False),  # not 0x7F0..0x7FF: CAN 2.0 (and the decoder) forbid ID[10:4] all recessive
    (0x1ABCDEF0, b"\x00\x00\xff", True, False),
    (0x00000000, bytes(8), True, False),
    (0x1FBFFFFF, longest_payload(0x1FBFFFFF, 8, extended=True), True, False),
    (0x123, b"", False, True),  # remote, DLC 0 (the decoder reads a data field after any DLC, remote or not)
    (0x0ABCDE, b"", True, True),
]


@needs_sigrok
@pytest.mark.parametrize("bitrate", STANDARD_BITRATES)
def test_sigrok_decodes_our_bits(bitrate: int, tmp_path: Path) -> None:
    ours = [frame_bits(ident, data, extended=extended, remote=remote) for ident, data, extended, remote in SIGROK_FRAMES]
    for frame, got in zip(ours, decode(ours, bitrate, tmp_path)):
        assert (got.identifier, got.extended, got.remote, got.dlc) == (frame.arbitration_id, frame.extended, frame.remote, frame.dlc)
        assert got.data == frame.data
        assert got.crc == frame.crc
        assert got.stuff_positions == frame.stuff_positions
        assert "ACK slot: ACK" in got.text and "End of frame" in got.text
