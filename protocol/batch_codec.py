"""Binary codec of sample batches: what the CPU wrote into the DSP's batch
memory block (thesis §3.2.3).

Layout (all little-endian)::

    offset size  field
    0      4     magic b"RALB"
    4      1     version (1)
    5      1     n_inputs   (D/A command channels, >= 1)
    6      1     n_outputs  (deflection channels, >= 1)
    7      1     reserved (0)
    8      8     seq            u64, batch sequence number from 0
    16     8     first_tick     u64, controller tick of the first sample
    24     4     n_samples      u32, >= 1
    28     4     dropped_before u32, samples the controller had to drop just before this batch
    32     8     sample_rate_hz f64
    40     8     sim_time_s     f64, simulated time of the first sample
    48     8     wall_time_s    f64, sender's wall clock when sent
    56     ...   float64 samples, channel-major: inputs then outputs, each n_samples long

Decoding rejects truncated, oversized or inconsistent payloads and
non-finite samples with :class:`~protocol.errors.BatchDecodeError`.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.errors import BatchDecodeError

MAGIC: Final[bytes] = b"RALB"
VERSION: Final[int] = 1
HEADER: Final[struct.Struct] = struct.Struct("<4sBBBBQQIIddd")
HEADER_SIZE: Final[int] = HEADER.size
MAX_SAMPLES: Final[int] = 1 << 20


@dataclass(frozen=True)
class SampleBatch:
    """One batch of ``n_samples`` samples of every input and output channel."""

    seq: int
    first_tick: int
    sample_rate_hz: float
    sim_time_s: float
    wall_time_s: float
    inputs: npt.NDArray[np.float64]
    outputs: npt.NDArray[np.float64]
    dropped_before: int = 0

    @property
    def n_samples(self) -> int:
        return int(self.inputs.shape[1])


def encode_batch(batch: SampleBatch) -> bytes:
    """Serialise a batch; validates shapes and values first."""
    inputs = np.ascontiguousarray(batch.inputs, dtype="<f8")
    outputs = np.ascontiguousarray(batch.outputs, dtype="<f8")
    if inputs.ndim != 2 or outputs.ndim != 2:
        raise ValueError("inputs and outputs must be 2-D (channels, samples)")
    n = inputs.shape[1]
    if outputs.shape[1] != n:
        raise ValueError(f"inputs have {n} samples, outputs {outputs.shape[1]}")
    if not 1 <= n <= MAX_SAMPLES:
        raise ValueError(f"a batch holds 1..{MAX_SAMPLES} samples, got {n}")
    if not (1 <= inputs.shape[0] <= 255 and 1 <= outputs.shape[0] <= 255):
        raise ValueError("a batch has 1..255 input and output channels")
    # As decode_batch checks: a non-finite sample makes the sum non-finite; only a
    # non-finite sum (or finite samples whose sum overflows) takes the per-sample check.
    if not math.isfinite(float(inputs.sum()) + float(outputs.sum())) and not (np.isfinite(inputs).all() and np.isfinite(outputs).all()):
        raise ValueError("batch samples must be finite")
    if batch.sample_rate_hz <= 0 or not math.isfinite(batch.sample_rate_hz):
        raise ValueError("sample rate must be positive")
    # Reject here what decode_batch would reject (or struct.pack would fail on).
    if not (math.isfinite(batch.sim_time_s) and batch.sim_time_s >= 0 and math.isfinite(batch.wall_time_s)):
        raise ValueError("time stamps must be finite and sim time non-negative")
    for name, value, bits in (("seq", batch.seq, 64), ("first_tick", batch.first_tick, 64), ("dropped_before", batch.dropped_before, 32)):
        if not 0 <= value < (1 << bits):
            raise ValueError(f"{name} must be 0..2**{bits}-1, got {value}")
    header = HEADER.pack(
        MAGIC,
        VERSION,
        inputs.shape[0],
        outputs.shape[0],
        0,
        batch.seq,
        batch.first_tick,
        n,
        batch.dropped_before,
        batch.sample_rate_hz,
        batch.sim_time_s,
        batch.wall_time_s,
    )
    return header + inputs.tobytes() + outputs.tobytes()


def decode_batch(payload: bytes | bytearray | memoryview) -> SampleBatch:
    """Parse and validate a batch payload."""
    data = payload if type(payload) is bytes else bytes(payload)
    if len(data) < HEADER_SIZE:
        raise BatchDecodeError(f"batch truncated: {len(data)} bytes, the header alone is {HEADER_SIZE}")
    magic, version, n_in, n_out, reserved, seq, first_tick, n, dropped, rate, sim_t, wall_t = HEADER.unpack_from(data)
    if magic != MAGIC:
        raise BatchDecodeError(f"not a sample batch: magic {magic!r}")
    if version != VERSION:
        raise BatchDecodeError(f"unsupported batch version {version} (this build reads {VERSION})")
    if reserved != 0:
        raise BatchDecodeError("reserved header byte is not zero")
    if n_in < 1 or n_out < 1:
        raise BatchDecodeError(f"batch must have input and output channels, got {n_in} and {n_out}")
    if not 1 <= n <= MAX_SAMPLES:
        raise BatchDecodeError(f"batch sample count {n} outside 1..{MAX_SAMPLES}")
    if not (math.isfinite(rate) and rate > 0):
        raise BatchDecodeError(f"batch sample rate {rate} is not positive")
    if not (math.isfinite(sim_t) and sim_t >= 0 and math.isfinite(wall_t)):
        raise BatchDecodeError("batch time stamps must be finite and sim time non-negative")
    expected = HEADER_SIZE + 8 * (n_in + n_out) * n
    if len(data) != expected:
        kind = "truncated" if len(data) < expected else "has trailing bytes"
        raise BatchDecodeError(f"batch {kind}: {len(data)} bytes, header says {expected}")
    samples = np.frombuffer(data, dtype="<f8", offset=HEADER_SIZE).reshape(n_in + n_out, n).copy()
    # A NaN or an infinity anywhere makes the sum non-finite (and nothing turns a
    # non-finite sum finite again): one reduction instead of isfinite + all on
    # the batch -> interrupt path. Only a non-finite sum (a NaN, an infinity, or
    # finite samples whose sum overflows) takes the exact per-sample check.
    if not math.isfinite(samples.sum()) and not np.isfinite(samples).all():
        raise BatchDecodeError("batch contains non-finite samples")
    # SampleBatch(...) field for field, without the frozen __init__'s object.__setattr__ per field
    batch = _new_batch(SampleBatch)
    batch.__dict__.update(
        seq=seq,
        first_tick=first_tick,
        sample_rate_hz=rate,
        sim_time_s=sim_t,
        wall_time_s=wall_t,
        inputs=samples[:n_in],
        outputs=samples[n_in:],
        dropped_before=dropped,
    )
    return batch


_new_batch = object.__new__
