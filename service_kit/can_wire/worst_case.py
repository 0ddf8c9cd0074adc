"""The longest frame a given identifier and data length can produce.

Davis et al.'s ``C_m`` (:func:`service_kit.can_wire.timing.worst_case_bits`)
assumes ``floor((g + 8 s - 1) / 4)`` stuff bits, which needs SOF..CRC to
follow the pattern ``00000 1111 0000 1111 ...`` throughout; the fixed bits
of a frame (IDE, r0, SRR, the DLC) and the CRC that the data determine break
that pattern, so a real frame is often shorter. :func:`longest_payload`
finds, for one identifier and DLC, a payload whose frame has the most (or,
``shortest=True``, the fewest) stuff bits, exactly: a dynamic programme over the data bits whose state is the
CRC register and the current run of equal bits (value and length),
2^15 x 8 states, then the CRC sequence's own stuff bits from each final
state. It returns the payload; :func:`service_kit.can_wire.bits.frame_bits`
then gives its bits.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from service_kit.can_wire.bits import CRC15_POLY, FrameBits, frame_bits

_UNREACHABLE = -(1 << 20)
_REACHABLE_ABOVE = _UNREACHABLE // 2
_N_STATES = (1 << 15) * 8
"""(CRC register, run value 0/1, run length 1..4) packed as crc * 8 + value * 4 + length - 1."""


def _step(
    crc: npt.NDArray[np.int64], value: npt.NDArray[np.int64], length: npt.NDArray[np.int64], bit: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    feedback = bit ^ ((crc >> 14) & 1)
    new_crc = ((crc << 1) & 0x7FFF) ^ (feedback * CRC15_POLY)
    same = value == bit
    new_length = np.where(same, length + 1, 1)
    stuffed = new_length == 5
    new_value = np.where(stuffed, 1 - bit, bit)
    new_length = np.where(stuffed, 1, new_length)
    return new_crc, new_value, new_length, stuffed.astype(np.int64)


def _state_after(bits: list[int]) -> tuple[int, int, int, int]:
    """CRC register, run value, run length and stuff count after ``bits`` (stuffed as sent)."""
    crc = np.array([0], dtype=np.int64)
    value = np.array([-1], dtype=np.int64)
    length = np.array([0], dtype=np.int64)
    count = 0
    for bit in bits:
        crc, value, length, stuffed = _step(crc, value, length, bit)
        count += int(stuffed[0])
    return int(crc[0]), int(value[0]), int(length[0]), count


def longest_payload(arbitration_id: int, n_bytes: int, *, extended: bool = False, shortest: bool = False) -> bytes:
    """A payload of ``n_bytes`` that gives the frame ``arbitration_id`` the
    most stuff bits any payload can (module docstring); ``shortest=True``:
    the fewest."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"classical CAN carries 0..8 data bytes, got {n_bytes}")
    if n_bytes == 0:
        return b""
    header = list(frame_bits(arbitration_id, bytes(n_bytes), extended=extended).unstuffed[: -(15 + 8 * n_bytes)])
    crc0, value0, length0, count0 = _state_after(header)
    states = np.arange(_N_STATES, dtype=np.int64)
    crc = states >> 3
    value = (states >> 2) & 1
    length = (states & 3) + 1
    sign = -1 if shortest else 1  # the programme maximises sign * stuff bits
    nexts: list[npt.NDArray[np.int64]] = []
    adds: list[npt.NDArray[np.int64]] = []
    for bit in (0, 1):
        c, v, n, s = _step(crc, value, length, bit)
        nexts.append(c * 8 + v * 4 + n - 1)
        adds.append(sign * s)
    # the best of all predecessors of each state: both bits' transitions sorted by target once, then a max per group
    targets = np.concatenate(nexts)
    order = np.argsort(targets, kind="stable")
    sorted_targets = targets[order]
    group_starts = np.flatnonzero(np.r_[True, sorted_targets[1:] != sorted_targets[:-1]])
    group_targets = sorted_targets[group_starts]
    add_sorted = np.concatenate(adds)[order].astype(np.int32)
    source_sorted = np.concatenate([states, states])[order]
    # unreachable states carry _UNREACHABLE (plus at most 64 steps of +-1): far below any reachable count
    best = np.full(_N_STATES, _UNREACHABLE, dtype=np.int32)
    best[crc0 * 8 + value0 * 4 + length0 - 1] = sign * count0
    history = [best]
    for _ in range(8 * n_bytes):
        candidates = best[source_sorted] + add_sorted
        best = np.full(_N_STATES, _UNREACHABLE, dtype=np.int32)
        best[group_targets] = np.maximum.reduceat(candidates, group_starts)
        history.append(best)
    # the CRC sequence is the final register; stuff it on from each state's run
    tail_crc, tail_value, tail_length = crc, value, length
    tail_count = np.zeros(_N_STATES, dtype=np.int64)
    for i in range(15):
        bit_i = (crc >> (14 - i)) & 1
        same = tail_value == bit_i
        run = np.where(same, tail_length + 1, 1)
        stuffed = run == 5
        tail_value = np.where(stuffed, 1 - bit_i, bit_i)
        tail_length = np.where(stuffed, 1, run)
        tail_count += stuffed
    del tail_crc
    total = np.where(best > _REACHABLE_ABOVE, best + sign * tail_count, _UNREACHABLE)
    state = int(np.argmax(total))
    bits: list[int] = []
    group_ends = np.r_[group_starts[1:], len(order)]
    for step in range(8 * n_bytes, 0, -1):
        before = history[step - 1]
        group = int(np.searchsorted(group_targets, state))
        for k in order[group_starts[group] : group_ends[group]]:
            bit, source = divmod(int(k), _N_STATES)
            if before[source] > _REACHABLE_ABOVE and before[source] + adds[bit][source] == history[step][state]:
                state = source
                bits.append(bit)
                break
        else:  # pragma: no cover - every reachable state has a predecessor
            raise AssertionError("no predecessor")
    bits.reverse()
    return bytes(int("".join(map(str, bits[i : i + 8])), 2) for i in range(0, len(bits), 8))


def longest_frame(arbitration_id: int, n_bytes: int, *, extended: bool = False) -> FrameBits:
    """The frame of :func:`longest_payload`."""
    return frame_bits(arbitration_id, longest_payload(arbitration_id, n_bytes, extended=extended), extended=extended)


def shortest_frame(arbitration_id: int, n_bytes: int, *, extended: bool = False) -> FrameBits:
    """The frame with the fewest stuff bits any payload of ``n_bytes`` gives ``arbitration_id``."""
    return frame_bits(arbitration_id, longest_payload(arbitration_id, n_bytes, extended=extended, shortest=True), extended=extended)
