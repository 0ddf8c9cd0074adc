"""Sample-batch codec (protocol.batch_codec): bit-exact round trips of any
shape, and every truncated, padded or inconsistent payload rejected with
BatchDecodeError -- never anything else."""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol import batch_codec as bc
from protocol.batch_codec import HEADER_SIZE, MAGIC, MAX_SAMPLES, VERSION, SampleBatch, decode_batch, encode_batch
from protocol.errors import BatchDecodeError, ProtocolError

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

finite = st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True, width=64)
EXTREMES = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, -2.225073858507201e-308, 1.7976931348623157e308, -1.7976931348623157e308, 1.0, -1.0]


@st.composite
def batches(draw: st.DrawFn, max_samples: int = 500) -> SampleBatch:
    n = draw(st.integers(min_value=1, max_value=max_samples))
    n_in = draw(st.integers(min_value=1, max_value=4))
    n_out = draw(st.integers(min_value=1, max_value=4))
    elements = st.one_of(finite, st.sampled_from(EXTREMES))
    return SampleBatch(
        seq=draw(st.integers(0, 2**64 - 1)),
        first_tick=draw(st.integers(0, 2**64 - 1)),
        sample_rate_hz=draw(st.floats(min_value=0.0, exclude_min=True, allow_infinity=False)),
        sim_time_s=draw(st.floats(min_value=0.0, allow_infinity=False)),
        wall_time_s=draw(finite),
        inputs=draw(hnp.arrays(np.float64, (n_in, n), elements=elements)),
        outputs=draw(hnp.arrays(np.float64, (n_out, n), elements=elements)),
        dropped_before=draw(st.integers(0, 2**32 - 1)),
    )


def _batch(n_in: int = 2, n_out: int = 2, n: int = 5, **changes: object) -> SampleBatch:
    rng = np.random.default_rng(n_in * 100 + n_out * 10 + n)
    fields: dict[str, object] = {
        "seq": 7,
        "first_tick": 140,
        "sample_rate_hz": 200.0,
        "sim_time_s": 0.7,
        "wall_time_s": 1.7e9,
        "inputs": rng.standard_normal((n_in, n)),
        "outputs": rng.standard_normal((n_out, n)),
        "dropped_before": 0,
    }
    fields.update(changes)
    return SampleBatch(**fields)  # type: ignore[arg-type]


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _assert_same(a: SampleBatch, b: SampleBatch) -> None:
    assert (a.seq, a.first_tick, a.dropped_before) == (b.seq, b.first_tick, b.dropped_before)
    for x, y in ((a.sample_rate_hz, b.sample_rate_hz), (a.sim_time_s, b.sim_time_s), (a.wall_time_s, b.wall_time_s)):
        assert struct.pack("<d", x) == struct.pack("<d", y)
    assert a.inputs.shape == b.inputs.shape and a.outputs.shape == b.outputs.shape
    assert _bits(a.inputs) == _bits(b.inputs)
    assert _bits(a.outputs) == _bits(b.outputs)


# --- round trips ---------------------------------------------------------------------


@FAST
@given(batch=batches())
def test_round_trip_is_bit_exact(batch: SampleBatch) -> None:
    payload = encode_batch(batch)
    n_in, n = batch.inputs.shape
    n_out = batch.outputs.shape[0]
    assert len(payload) == HEADER_SIZE + 8 * (n_in + n_out) * n
    back = decode_batch(payload)
    _assert_same(batch, back)
    assert back.n_samples == n
    assert back.inputs.dtype == np.float64 and back.outputs.dtype == np.float64
    assert encode_batch(back) == payload


def test_round_trip_of_extremes_and_signed_zero() -> None:
    values = np.array(EXTREMES * 3).reshape(3, len(EXTREMES))
    batch = _batch(inputs=values, outputs=values[::-1].copy(), n_in=3, n_out=3, n=len(EXTREMES))
    back = decode_batch(encode_batch(batch))
    _assert_same(batch, back)
    assert math.copysign(1.0, back.inputs[0, 1]) == -1.0  # -0.0 survives


@pytest.mark.parametrize("n_in,n_out,n", [(1, 1, 1), (4, 4, 500), (1, 4, 1), (4, 1, 2), (255, 255, 1), (1, 1, 4096)])
def test_round_trip_shape_corners(n_in: int, n_out: int, n: int) -> None:
    batch = _batch(n_in, n_out, n)
    _assert_same(batch, decode_batch(encode_batch(batch)))


def test_decode_accepts_bytearray_and_memoryview_and_copies() -> None:
    batch = _batch()
    payload = bytearray(encode_batch(batch))
    back = decode_batch(memoryview(payload))
    _assert_same(batch, decode_batch(payload))
    payload[HEADER_SIZE : HEADER_SIZE + 8] = struct.pack("<d", 123.0)
    assert back.inputs[0, 0] == batch.inputs[0, 0]  # decoded arrays do not alias the buffer
    back.inputs[0, 0] = 1.0  # and are writable


def test_header_layout_matches_the_documented_offsets() -> None:
    batch = _batch(3, 2, 4, seq=0x0102030405060708, first_tick=0x1112131415161718, dropped_before=9, sample_rate_hz=250.0, sim_time_s=1.5, wall_time_s=-2.5)
    payload = encode_batch(batch)
    assert HEADER_SIZE == 56
    assert payload[0:4] == b"RALB" == MAGIC
    assert payload[4] == VERSION == 1
    assert (payload[5], payload[6], payload[7]) == (3, 2, 0)
    assert struct.unpack_from("<Q", payload, 8)[0] == 0x0102030405060708
    assert struct.unpack_from("<Q", payload, 16)[0] == 0x1112131415161718
    assert struct.unpack_from("<I", payload, 24)[0] == 4
    assert struct.unpack_from("<I", payload, 28)[0] == 9
    assert struct.unpack_from("<ddd", payload, 32) == (250.0, 1.5, -2.5)
    samples = np.frombuffer(payload, dtype="<f8", offset=56).reshape(5, 4)
    np.testing.assert_array_equal(samples[:3], batch.inputs)  # channel-major, inputs first
    np.testing.assert_array_equal(samples[3:], batch.outputs)


def test_encode_normalises_dtype_and_memory_layout() -> None:
    batch = _batch(2, 3, 6)
    reference = encode_batch(batch)
    fortran = SampleBatch(**{**batch.__dict__, "inputs": np.asfortranarray(batch.inputs), "outputs": np.asfortranarray(batch.outputs)})
    strided = SampleBatch(**{**batch.__dict__, "inputs": np.repeat(batch.inputs, 2, axis=1)[:, ::2], "outputs": batch.outputs.T.copy().T})
    big_endian = SampleBatch(**{**batch.__dict__, "inputs": batch.inputs.astype(">f8"), "outputs": batch.outputs.astype(">f8")})
    nested = SampleBatch(**{**batch.__dict__, "inputs": batch.inputs.tolist(), "outputs": batch.outputs.tolist()})
    for variant in (fortran, strided, big_endian, nested):
        assert encode_batch(variant) == reference
    ints = _batch(1, 1, 3, inputs=np.array([[1, 2, 3]]), outputs=np.array([[-1, 0, 1]], dtype=np.int16))
    back = decode_batch(encode_batch(ints))
    np.testing.assert_array_equal(back.inputs, [[1.0, 2.0, 3.0]])


# --- decode rejects ------------------------------------------------------------------


def _reject(payload: bytes | bytearray, *needles: str) -> BatchDecodeError:
    with pytest.raises(BatchDecodeError) as info:
        decode_batch(bytes(payload))
    for needle in needles:
        assert needle in str(info.value), f"{needle!r} not in {info.value}"
    return info.value


@pytest.mark.parametrize("n_in,n_out,n", [(1, 1, 1), (2, 2, 5), (4, 3, 7)])
def test_every_truncation_is_rejected(n_in: int, n_out: int, n: int) -> None:
    payload = encode_batch(_batch(n_in, n_out, n))
    for cut in range(len(payload)):
        _reject(payload[:cut], "truncated")


@FAST
@given(batch=batches(max_samples=50), data=st.data())
def test_random_truncation_is_rejected(batch: SampleBatch, data: st.DataObject) -> None:
    payload = encode_batch(batch)
    _reject(payload[: data.draw(st.integers(0, len(payload) - 1))], "truncated")


@pytest.mark.parametrize("extra", [b"\x00", b"\x00" * 7, b"\x00" * 8, b"\xff" * 16, b"RALB"])
def test_appended_bytes_are_rejected(extra: bytes) -> None:
    _reject(encode_batch(_batch()) + extra, "trailing bytes")


def test_a_whole_extra_sample_row_is_rejected() -> None:
    payload = encode_batch(_batch(2, 2, 5))
    _reject(payload + payload[HEADER_SIZE : HEADER_SIZE + 8 * 4], "trailing bytes")


def _patched(fmt: str, offset: int, value: object, batch: SampleBatch | None = None) -> bytearray:
    payload = bytearray(encode_batch(batch or _batch()))
    struct.pack_into(fmt, payload, offset, value)
    return payload


@pytest.mark.parametrize("magic", [b"RALC", b"ralb", b"\x00\x00\x00\x00", b"BLAR"])
def test_bad_magic(magic: bytes) -> None:
    _reject(_patched("<4s", 0, magic), "magic")


@pytest.mark.parametrize("version", [0, 2, 255])
def test_bad_version(version: int) -> None:
    _reject(_patched("<B", 4, version), "version")


@pytest.mark.parametrize("reserved", [1, 0x80, 255])
def test_reserved_byte_must_be_zero(reserved: int) -> None:
    _reject(_patched("<B", 7, reserved), "reserved")


@pytest.mark.parametrize("offset", [5, 6])
def test_zero_channels(offset: int) -> None:
    batch = _batch(1, 1, 4)
    payload = _patched("<B", offset, 0, batch)
    _reject(payload, "channels")
    # also when the length is made consistent with the zero count
    _reject(payload[: HEADER_SIZE + 8 * 4], "channels")


def test_zero_samples() -> None:
    payload = _patched("<I", 24, 0)
    _reject(payload, "sample count 0")
    _reject(payload[:HEADER_SIZE], "sample count 0")


def test_sample_count_beyond_the_maximum() -> None:
    _reject(_patched("<I", 24, MAX_SAMPLES + 1)[:HEADER_SIZE], "outside")
    _reject(_patched("<I", 24, 2**32 - 1)[:HEADER_SIZE], "outside")


@pytest.mark.parametrize("claimed", [6, 7, 100, MAX_SAMPLES])
def test_header_claiming_more_samples_than_present(claimed: int) -> None:
    _reject(_patched("<I", 24, claimed, _batch(2, 2, 5)), "truncated")


@pytest.mark.parametrize("claimed", [1, 4])
def test_header_claiming_fewer_samples_than_present(claimed: int) -> None:
    _reject(_patched("<I", 24, claimed, _batch(2, 2, 5)), "trailing bytes")


@pytest.mark.parametrize("offset,value", [(5, 3), (6, 1), (5, 255)])
def test_channel_counts_inconsistent_with_length(offset: int, value: int) -> None:
    _reject(_patched("<B", offset, value, _batch(2, 2, 5)))


@pytest.mark.parametrize("rate", [0.0, -0.0, -200.0, math.nan, math.inf, -math.inf])
def test_bad_sample_rate(rate: float) -> None:
    _reject(_patched("<d", 32, rate), "sample rate")


@pytest.mark.parametrize("offset,value", [(40, -0.1), (40, math.nan), (40, math.inf), (48, math.nan), (48, math.inf), (48, -math.inf)])
def test_bad_time_stamps(offset: int, value: float) -> None:
    _reject(_patched("<d", offset, value), "time stamps")


NAN_PATTERNS = [0x7FF8000000000000, 0xFFF8000000000000, 0x7FF0000000000001, 0x7FF4000000000000, 0xFFFFFFFFFFFFFFFF, 0x7FF0000000000000, 0xFFF0000000000000]


@pytest.mark.parametrize("pattern", NAN_PATTERNS, ids=hex)
@pytest.mark.parametrize("index", [0, 9, 10, 19])
def test_non_finite_samples_are_rejected(pattern: int, index: int) -> None:
    # 2 inputs + 2 outputs x 5 samples: index 0 = first input, 19 = last output sample
    _reject(_patched("<Q", HEADER_SIZE + 8 * index, pattern, _batch(2, 2, 5)), "non-finite")


@FAST
@given(batch=batches(max_samples=40), data=st.data())
def test_nan_anywhere_is_rejected(batch: SampleBatch, data: st.DataObject) -> None:
    payload = bytearray(encode_batch(batch))
    total = (len(payload) - HEADER_SIZE) // 8
    index = data.draw(st.integers(0, total - 1))
    value = data.draw(st.sampled_from([math.nan, math.inf, -math.inf]))
    struct.pack_into("<d", payload, HEADER_SIZE + 8 * index, value)
    _reject(payload, "non-finite")


def test_finite_samples_whose_sum_overflows_are_accepted() -> None:
    # the decoder sums the samples first; an overflowing sum of finite samples is not a rejection
    big = np.full((2, 5), np.finfo(np.float64).max)
    batch = decode_batch(encode_batch(_batch(2, 2, 5, inputs=big, outputs=-big)))
    assert _bits(batch.inputs) == _bits(big) and _bits(batch.outputs) == _bits(-big)
    payload = bytearray(encode_batch(_batch(2, 2, 5, inputs=big, outputs=big)))
    struct.pack_into("<d", payload, HEADER_SIZE + 8 * 13, math.inf)
    _reject(payload, "non-finite")


def test_decode_error_is_a_protocol_error() -> None:
    assert issubclass(BatchDecodeError, ProtocolError)
    assert issubclass(BatchDecodeError, ValueError)


@settings(max_examples=250, deadline=None)
@given(payload=st.binary(max_size=200))
def test_arbitrary_bytes_raise_only_batch_decode_error(payload: bytes) -> None:
    try:
        decode_batch(payload)
    except BatchDecodeError:
        pass


@settings(max_examples=150, deadline=None)
@given(
    n_in=st.integers(0, 5),
    n_out=st.integers(0, 5),
    n=st.integers(0, 8),
    reserved=st.sampled_from([0, 0, 0, 1]),
    floats=st.lists(st.floats(), min_size=3, max_size=3),
    tail=st.binary(max_size=400),
)
def test_plausible_headers_with_arbitrary_bodies_raise_only_batch_decode_error(
    n_in: int, n_out: int, n: int, reserved: int, floats: list[float], tail: bytes
) -> None:
    payload = bc.HEADER.pack(MAGIC, VERSION, n_in, n_out, reserved, 0, 0, n, 0, *floats) + tail
    try:
        batch = decode_batch(payload)
    except BatchDecodeError:
        return
    assert batch.inputs.shape == (n_in, n) and batch.outputs.shape == (n_out, n)
    assert np.all(np.isfinite(batch.inputs)) and np.all(np.isfinite(batch.outputs))


@FAST
@given(batch=batches(max_samples=20), data=st.data())
def test_corrupted_payloads_raise_only_batch_decode_error(batch: SampleBatch, data: st.DataObject) -> None:
    payload = bytearray(encode_batch(batch))
    for _ in range(data.draw(st.integers(1, 4))):
        payload[data.draw(st.integers(0, len(payload) - 1))] = data.draw(st.integers(0, 255))
    try:
        decode_batch(bytes(payload))
    except BatchDecodeError:
        pass


# --- encode rejects ------------------------------------------------------------------


@pytest.mark.parametrize(
    "changes,needle",
    [
        ({"outputs": np.zeros((2, 4))}, "samples"),
        ({"inputs": np.zeros((2, 6))}, "samples"),
        ({"inputs": np.zeros(5)}, "2-D"),
        ({"outputs": np.zeros((1, 2, 5))}, "2-D"),
        ({"inputs": np.zeros((0, 5))}, "channels"),
        ({"outputs": np.zeros((0, 5))}, "channels"),
        ({"inputs": np.zeros((256, 5))}, "channels"),
        ({"inputs": np.zeros((2, 0)), "outputs": np.zeros((2, 0))}, "1.."),
        ({"inputs": np.zeros((1, MAX_SAMPLES + 1)), "outputs": np.zeros((1, MAX_SAMPLES + 1))}, "1.."),
        ({"sample_rate_hz": 0.0}, "sample rate"),
        ({"sample_rate_hz": -1.0}, "sample rate"),
        ({"sample_rate_hz": math.nan}, "sample rate"),
        ({"sample_rate_hz": math.inf}, "sample rate"),
        ({"sim_time_s": -1.0}, "time"),
        ({"sim_time_s": math.nan}, "time"),
        ({"wall_time_s": math.inf}, "time"),
        ({"seq": -1}, "seq"),
        ({"seq": 2**64}, "seq"),
        ({"first_tick": -1}, "first_tick"),
        ({"dropped_before": 2**32}, "dropped_before"),
        ({"dropped_before": -1}, "dropped_before"),
    ],
    ids=lambda x: repr(x)[:40] if isinstance(x, dict) else x,
)
def test_encode_rejects_inconsistent_batches(changes: dict[str, object], needle: str) -> None:
    with pytest.raises(ValueError, match=None) as info:
        encode_batch(_batch(2, 2, 5, **changes))
    assert needle in str(info.value)


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("where", ["inputs", "outputs"])
def test_encode_rejects_non_finite_samples(value: float, where: str) -> None:
    batch = _batch(2, 2, 5)
    array = getattr(batch, where).copy()
    array[1, 3] = value
    with pytest.raises(ValueError, match="finite"):
        encode_batch(SampleBatch(**{**batch.__dict__, where: array}))
