"""Bit time and wire time of classical CAN frames, and Davis et al.'s bound.

Times are integer nanoseconds: every usual bit rate (10 k .. 1 Mbit/s,
800 kbit/s included) has a whole number of nanoseconds per bit, so the
wire model's arithmetic is exact and the same on every machine.

:func:`worst_case_bits` is the longest a frame with ``s`` data bytes can
be, stuff bits and the 3-bit intermission included: Davis, Burns, Bril and
Lukkien, "Controller Area Network (CAN) schedulability analysis: refuted,
revisited and revised", Real-Time Systems 35 (2007), eq. for ``C_m``:
``g + 8 s + 13 + floor((g + 8 s - 1) / 4)`` with ``g = 34`` (11-bit id) or
``54`` (29-bit id), i.e. ``55 + 10 s`` and ``80 + 10 s`` bits.
"""

from __future__ import annotations

STANDARD_BITRATES: tuple[int, ...] = (125_000, 250_000, 500_000, 1_000_000)
NS_PER_S = 1_000_000_000


def bit_time_ns(bitrate: int) -> int:
    """Nanoseconds per bit; ValueError for a rate that is not a whole number of them."""
    if bitrate <= 0 or NS_PER_S % bitrate:
        raise ValueError(f"bit rate {bitrate} bit/s has no whole number of nanoseconds per bit")
    return NS_PER_S // bitrate


def wire_time_ns(n_bits: int, bitrate: int) -> int:
    """Time ``n_bits`` occupy the bus at ``bitrate``: bits x bit time."""
    return n_bits * bit_time_ns(bitrate)


def worst_case_bits(n_bytes: int, *, extended: bool = False) -> int:
    """Davis et al. 2007's ``C_m`` in bits (module docstring)."""
    if not 0 <= n_bytes <= 8:
        raise ValueError(f"classical CAN carries 0..8 data bytes, got {n_bytes}")
    g = 54 if extended else 34
    return g + 8 * n_bytes + 13 + (g + 8 * n_bytes - 1) // 4
