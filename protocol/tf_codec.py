"""Binary codec of transfer-function snapshots: the DSP's current estimates,
which the CPU downloads every ``tf_download_samples`` samples (thesis §4.2.2).

A snapshot at N = 2048 is 1025 bins of eleven float64 arrays. As JSON it was
tens of kilobytes of decimal text whose decoding held the controller's GIL for
about a millisecond beside a 1 kHz loop; here it is one header and the arrays'
own bytes, decoded into read-only numpy views of the payload (no Python float
per bin, no copy).

Layout (all little-endian)::

    offset size  field
    0      4     magic b"RALT"
    4      1     version (1)
    5      1     estimates: bit i set = TF_NAMES[i] present
                 (H11, H12, H21, H22, Htot: bits 0..4; bits 5..7 zero)
    6      2     reserved (0)
    8      8     seq          u64 (< 2**63), the DSP's snapshot number from 0
    16     8     batch_seq    u64 (< 2**63), the last batch the estimates include
    24     4     n_bins       u32, 0..MAX_BINS
    28     4     reserved (0)
    32     8     sim_time_s   f64, finite, 0..MAX_ABS
    40     8     wall_time_s  f64, finite, 0..MAX_ABS (the DSP's clock when taken)
    48     ...   float64 arrays of n_bins each: freqs_hz, then for every estimate
                 present (in bit order) its magnitude and its phase_rad
    ...    n_bins  valid, one byte per bin: 0 or 1

Every float is finite and within ±MAX_ABS (the bound of every quantity of the
contract, :data:`protocol.messages.MAX_ABS`). Decoding rejects a wrong magic,
version, reserved field, length, bit or value with
:class:`~protocol.errors.TfDecodeError` (a :class:`~protocol.errors.ProtocolError`);
encoding refuses what decoding would refuse, with ``ValueError``.
"""

from __future__ import annotations

import math
import struct
from typing import Final

import numpy as np

from protocol.errors import TfDecodeError
from protocol.messages import MAX_ABS, MAX_BINS, TF_NAMES, TfName, TfSnapshot, TransferFunction

MAGIC: Final[bytes] = b"RALT"
VERSION: Final[int] = 1
HEADER: Final[struct.Struct] = struct.Struct("<4sBBHQQIIdd")
HEADER_SIZE: Final[int] = HEADER.size
MAX_SEQ: Final[int] = 2**63
_ALL_BITS: Final[int] = (1 << len(TF_NAMES)) - 1
_BIT: Final[dict[str, int]] = {name: 1 << i for i, name in enumerate(TF_NAMES)}
_NAMES_OF_MASK: Final[tuple[tuple[TfName, ...], ...]] = tuple(tuple(name for i, name in enumerate(TF_NAMES) if mask >> i & 1) for mask in range(_ALL_BITS + 1))


def payload_size(n_bins: int, n_estimates: int) -> int:
    """Bytes of a snapshot of ``n_bins`` bins and ``n_estimates`` estimates."""
    return HEADER_SIZE + 8 * (1 + 2 * n_estimates) * n_bins + n_bins


def encode_tf(snapshot: TfSnapshot) -> bytes:
    """Serialise a snapshot; validates it first (``ValueError``: what :func:`decode_tf` would refuse)."""
    mask = 0
    for name in snapshot.estimates:
        mask |= _BIT[name]
    names = _NAMES_OF_MASK[mask]
    n = snapshot.freqs_hz.size
    block = np.empty((1 + 2 * len(names), n), dtype="<f8")
    block[0] = snapshot.freqs_hz
    for i, name in enumerate(names):
        tf = snapshot.estimates[name]
        block[1 + 2 * i] = tf.magnitude
        block[2 + 2 * i] = tf.phase_rad
    if block.size and not (block.min() >= -MAX_ABS and block.max() <= MAX_ABS):  # NaN fails both comparisons
        raise ValueError(f"transfer-function values must be finite and within ±{MAX_ABS:g}")
    for what, value in (("sim_time_s", snapshot.sim_time_s), ("wall_time_s", snapshot.wall_time_s)):
        if not (math.isfinite(value) and 0.0 <= value <= MAX_ABS):
            raise ValueError(f"{what} must be finite and within 0..{MAX_ABS:g}, got {value}")
    for what, count in (("seq", snapshot.seq), ("batch_seq", snapshot.batch_seq)):
        if not 0 <= count < MAX_SEQ:
            raise ValueError(f"{what} must be 0..2**63-1, got {count}")
    header = HEADER.pack(MAGIC, VERSION, mask, 0, snapshot.seq, snapshot.batch_seq, n, 0, snapshot.sim_time_s, snapshot.wall_time_s)
    return b"".join((header, block.tobytes(), snapshot.valid.astype(np.uint8).tobytes()))


def decode_tf(payload: bytes | bytearray | memoryview) -> TfSnapshot:
    """Parse and validate a snapshot payload (:class:`~protocol.errors.TfDecodeError` if it breaks the layout).

    The arrays are read-only views of the payload's bytes (a ``bytes`` payload is used as is)."""
    data = payload if type(payload) is bytes else bytes(payload)
    if len(data) < HEADER_SIZE:
        raise TfDecodeError(f"TF snapshot truncated: {len(data)} bytes, the header alone is {HEADER_SIZE}")
    magic, version, mask, reserved, seq, batch_seq, n, reserved2, sim_t, wall_t = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise TfDecodeError(f"not a TF snapshot: magic {magic!r}")
    if version != VERSION:
        raise TfDecodeError(f"unsupported TF snapshot version {version} (this build reads {VERSION})")
    if reserved or reserved2:
        raise TfDecodeError("reserved header fields are not zero")
    if mask & ~_ALL_BITS:
        raise TfDecodeError(f"unknown estimates in mask {mask:#04x} (known: {', '.join(TF_NAMES)} in bits 0..4)")
    if n > MAX_BINS:
        raise TfDecodeError(f"TF snapshot bin count {n} above {MAX_BINS}")
    if seq >= MAX_SEQ or batch_seq >= MAX_SEQ:
        raise TfDecodeError("TF snapshot seq and batch_seq must be below 2**63")
    if not (math.isfinite(sim_t) and 0.0 <= sim_t <= MAX_ABS and math.isfinite(wall_t) and 0.0 <= wall_t <= MAX_ABS):
        raise TfDecodeError("TF snapshot time stamps must be finite and within 0..1e15")
    names = _NAMES_OF_MASK[mask]
    rows = 1 + 2 * len(names)
    expected = payload_size(n, len(names))
    if len(data) != expected:
        kind = "truncated" if len(data) < expected else "has trailing bytes"
        raise TfDecodeError(f"TF snapshot {kind}: {len(data)} bytes, header says {expected}")
    block = np.frombuffer(data, dtype="<f8", count=rows * n, offset=HEADER_SIZE).reshape(rows, n)
    if n and not (block.min() >= -MAX_ABS and block.max() <= MAX_ABS):  # NaN fails both comparisons
        raise TfDecodeError(f"TF snapshot values must be finite and within ±{MAX_ABS:g}")
    valid = np.frombuffer(data, dtype=np.uint8, count=n, offset=HEADER_SIZE + 8 * rows * n)
    if n and valid.max() > 1:
        raise TfDecodeError("TF snapshot valid mask holds bytes other than 0 and 1")
    estimates = {name: TransferFunction(block[1 + 2 * i], block[2 + 2 * i]) for i, name in enumerate(names)}
    return TfSnapshot(seq=seq, sim_time_s=sim_t, wall_time_s=wall_t, batch_seq=batch_seq, freqs_hz=block[0], valid=valid.view(np.bool_), estimates=estimates)
