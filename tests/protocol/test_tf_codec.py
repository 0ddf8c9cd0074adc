"""Transfer-function snapshot codec (protocol.tf_codec): bit-exact round trips,
the documented layout, and every truncated, padded, inconsistent or
non-finite payload rejected with TfDecodeError -- never anything else."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from protocol import messages as m
from protocol.errors import ProtocolError, TfDecodeError
from protocol.tf_codec import HEADER_SIZE, MAGIC, VERSION, decode_tf, encode_tf, payload_size

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

bounded = st.floats(min_value=-m.MAX_ABS, max_value=m.MAX_ABS, allow_nan=False, allow_subnormal=True, width=64)
EXTREMES = [0.0, -0.0, 5e-324, -5e-324, 2.2250738585072014e-308, m.MAX_ABS, -m.MAX_ABS, math.pi, -math.pi]


@st.composite
def snapshots(draw: st.DrawFn, max_bins: int = 40) -> m.TfSnapshot:
    n = draw(st.integers(min_value=0, max_value=max_bins))
    elements = st.one_of(bounded, st.sampled_from(EXTREMES))
    vec = hnp.arrays(np.float64, n, elements=elements)
    names = draw(st.lists(st.sampled_from(m.TF_NAMES), unique=True))
    return m.TfSnapshot(
        seq=draw(st.integers(0, 2**63 - 1)),
        sim_time_s=draw(st.floats(min_value=0.0, max_value=m.MAX_ABS)),
        wall_time_s=draw(st.floats(min_value=0.0, max_value=m.MAX_ABS)),
        batch_seq=draw(st.integers(0, 2**63 - 1)),
        freqs_hz=draw(vec),
        valid=draw(hnp.arrays(np.bool_, n)),
        estimates={name: m.TransferFunction(draw(vec), draw(vec)) for name in names},
    )


def _snap(n: int = 5, names: tuple[m.TfName, ...] = m.TF_NAMES) -> m.TfSnapshot:
    rng = np.random.default_rng(n)
    return m.TfSnapshot(
        seq=3,
        sim_time_s=12.5,
        wall_time_s=1.7e9,
        batch_seq=61,
        freqs_hz=np.arange(n) * 0.25,
        valid=rng.random(n) > 0.3,
        estimates={name: m.TransferFunction(rng.random(n) * 10, rng.uniform(-math.pi, math.pi, n)) for name in names},
    )


def _bits(a: np.ndarray) -> bytes:
    return np.ascontiguousarray(a, dtype="<f8").tobytes()


def _same_bits(a: m.TfSnapshot, b: m.TfSnapshot) -> None:
    assert (a.seq, a.batch_seq, a.sim_time_s, a.wall_time_s) == (b.seq, b.batch_seq, b.sim_time_s, b.wall_time_s)
    assert _bits(a.freqs_hz) == _bits(b.freqs_hz)
    assert a.valid.tolist() == b.valid.tolist()
    assert list(a.estimates) == list(b.estimates) or set(a.estimates) == set(b.estimates)
    for name, tf in a.estimates.items():
        assert _bits(tf.magnitude) == _bits(b.estimates[name].magnitude)
        assert _bits(tf.phase_rad) == _bits(b.estimates[name].phase_rad)


# --- round trips ---------------------------------------------------------------------


@FAST
@given(snap=snapshots())
def test_round_trip_is_bit_exact(snap: m.TfSnapshot) -> None:
    payload = encode_tf(snap)
    assert len(payload) == payload_size(snap.freqs_hz.size, len(snap.estimates))
    back = decode_tf(payload)
    _same_bits(snap, back)
    assert back == snap
    assert encode_tf(back) == payload


def test_the_arrays_are_typed_read_only_views_of_the_payload() -> None:
    payload = encode_tf(_snap(1025))
    back = decode_tf(payload)
    for arr in (back.freqs_hz, back.valid, *(a for tf in back.estimates.values() for a in (tf.magnitude, tf.phase_rad))):
        assert isinstance(arr, np.ndarray) and arr.ndim == 1 and arr.size == 1025
        assert not arr.flags.writeable
        assert np.shares_memory(arr, np.frombuffer(payload, dtype=np.uint8))  # no copy, no Python float per bin
    assert back.freqs_hz.dtype == np.float64 and back.valid.dtype == np.bool_
    with pytest.raises(ValueError):
        back.freqs_hz[0] = 1.0
    with pytest.raises(AttributeError):
        back.seq = 4  # type: ignore[misc]


def test_decode_accepts_bytearray_and_memoryview() -> None:
    snap = _snap()
    payload = encode_tf(snap)
    assert decode_tf(bytearray(payload)) == snap
    assert decode_tf(memoryview(payload)) == snap


def test_values_match_the_json_contract_it_replaces() -> None:
    """The binary snapshot carries the same numbers the JSON one did: Python's own
    float repr (what the pydantic JSON wrote) parses back to the decoded floats."""
    snap = _snap(64)
    as_json = json.loads(json.dumps(snap.as_json()))
    back = decode_tf(encode_tf(snap)).as_json()
    assert back == as_json
    assert set(as_json) == {"seq", "sim_time_s", "wall_time_s", "batch_seq", "freqs_hz", "valid", "estimates"}


def test_as_arrays_builds_complex_estimates() -> None:
    snap = m.TfSnapshot(
        seq=0,
        sim_time_s=0.0,
        batch_seq=3,
        freqs_hz=[1.0, 2.0, 3.0],
        valid=[True, False, True],
        estimates={"H11": m.TransferFunction([1.0, 2.0, 0.5], [0.0, math.pi / 2, -math.pi])},
    )
    arrays = decode_tf(encode_tf(snap)).as_arrays()
    assert set(arrays) == {"freqs_hz", "valid", "H11"}
    np.testing.assert_array_equal(arrays["freqs_hz"], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(arrays["valid"], [True, False, True])
    np.testing.assert_allclose(arrays["H11"], [1.0, 2j, -0.5], atol=1e-15)


def test_header_layout_matches_the_documented_offsets() -> None:
    snap = _snap(3, ("H12", "Htot"))
    payload = encode_tf(snap)
    assert payload[0:4] == MAGIC == b"RALT" and payload[4] == VERSION == 1
    assert payload[5] == 0b10010  # H12 is bit 1, Htot bit 4
    assert payload[6:8] == b"\0\0" and payload[28:32] == b"\0\0\0\0"
    assert struct.unpack_from("<QQI", payload, 8) == (3, 61, 3)
    assert struct.unpack_from("<dd", payload, 32) == (12.5, 1.7e9)
    assert HEADER_SIZE == 48
    floats = np.frombuffer(payload, dtype="<f8", count=5 * 3, offset=48).reshape(5, 3)
    np.testing.assert_array_equal(floats[0], snap.freqs_hz)
    np.testing.assert_array_equal(floats[1:], [snap.estimates[k].__getattribute__(a) for k in ("H12", "Htot") for a in ("magnitude", "phase_rad")])
    assert payload[48 + 8 * 15 :] == bytes(int(v) for v in snap.valid)


def test_the_snapshot_checks_its_shapes() -> None:
    with pytest.raises(ValueError, match="valid mask length"):
        m.TfSnapshot(seq=0, sim_time_s=0.0, batch_seq=0, freqs_hz=[1.0, 2.0], valid=[True], estimates={})
    with pytest.raises(ValueError, match="H12 length differs"):
        m.TfSnapshot(seq=0, sim_time_s=0.0, batch_seq=0, freqs_hz=[1.0, 2.0], valid=[True, True], estimates={"H12": m.TransferFunction([1.0], [0.0])})
    with pytest.raises(ValueError, match="magnitude has 2 bins, phase 1"):
        m.TransferFunction([1.0, 2.0], [0.0])
    with pytest.raises(ValueError, match="unknown estimate 'H33'"):
        m.TfSnapshot(seq=0, sim_time_s=0.0, batch_seq=0, freqs_hz=[1.0], valid=[True], estimates={"H33": m.TransferFunction([1.0], [0.0])})  # type: ignore[dict-item]
    with pytest.raises(ValueError, match="1-D"):
        m.TransferFunction(np.zeros((2, 2)), np.zeros((2, 2)))


# --- invalid payloads ----------------------------------------------------------------


def _patched(payload: bytes, offset: int, fmt: str, *values: object) -> bytes:
    out = bytearray(payload)
    struct.pack_into(fmt, out, offset, *values)
    return bytes(out)


def _rejects(payload: bytes, needle: str) -> None:
    with pytest.raises(TfDecodeError, match=needle):
        decode_tf(payload)


def test_every_truncation_and_any_trailing_byte_is_rejected() -> None:
    payload = encode_tf(_snap(4, ("H11",)))
    for cut in range(len(payload)):
        with pytest.raises(TfDecodeError):
            decode_tf(payload[:cut])
    _rejects(payload + b"\0", "trailing bytes")
    _rejects(payload + bytes(8 * 3 + 1), "trailing bytes")  # a whole extra bin's worth


@pytest.mark.parametrize(
    "offset,fmt,value,needle",
    [
        (0, "<4s", b"RALB", "not a TF snapshot"),
        (4, "<B", 2, "unsupported TF snapshot version 2"),
        (4, "<B", 0, "unsupported TF snapshot version 0"),
        (5, "<B", 0b100000, "unknown estimates"),
        (6, "<H", 1, "reserved"),
        (28, "<I", 7, "reserved"),
        (8, "<Q", 2**63, "below 2"),
        (16, "<Q", 2**64 - 1, "below 2"),
        (24, "<I", m.MAX_BINS + 1, "bin count"),
        (24, "<I", 5, "truncated"),
        (24, "<I", 3, "trailing bytes"),
        (32, "<d", math.nan, "time stamps"),
        (32, "<d", -1.0, "time stamps"),
        (40, "<d", math.inf, "time stamps"),
        (5, "<B", 0b11111, "truncated"),
        (5, "<B", 0b00001, "trailing bytes"),
    ],
)
def test_bad_headers_are_rejected(offset: int, fmt: str, value: object, needle: str) -> None:
    _rejects(_patched(encode_tf(_snap(4, ("H11", "H22"))), offset, fmt, value), needle)


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1.0000000000000002e15, -1e300])
@pytest.mark.parametrize("row", [0, 1, 4])
def test_non_finite_or_out_of_bound_values_are_rejected(bad: float, row: int) -> None:
    payload = encode_tf(_snap(4, ("H11", "H22")))
    _rejects(_patched(payload, HEADER_SIZE + 8 * (4 * row + 2), "<d", bad), "finite and within")


def test_valid_bytes_other_than_0_and_1_are_rejected() -> None:
    payload = encode_tf(_snap(4, ("H11",)))
    _rejects(payload[:-1] + b"\x02", "valid mask")


def test_decode_error_is_a_protocol_error() -> None:
    assert issubclass(TfDecodeError, ProtocolError)


@FAST
@given(payload=st.binary(max_size=200))
def test_arbitrary_bytes_raise_only_tf_decode_error(payload: bytes) -> None:
    try:
        decode_tf(payload)
    except TfDecodeError:
        pass


@FAST
@given(snap=snapshots(max_bins=8), data=st.data())
def test_corrupted_payloads_raise_only_tf_decode_error(snap: m.TfSnapshot, data: st.DataObject) -> None:
    payload = bytearray(encode_tf(snap))
    for _ in range(data.draw(st.integers(1, 4))):
        at = data.draw(st.integers(0, len(payload) - 1))
        payload[at] = data.draw(st.integers(0, 255))
    try:
        back = decode_tf(bytes(payload))
    except TfDecodeError:
        return
    assert all(np.isfinite(a).all() for tf in back.estimates.values() for a in (tf.magnitude, tf.phase_rad))


# --- encoding refuses what decoding would refuse ---------------------------------------------


@pytest.mark.parametrize("bad", [math.nan, math.inf, 2e15])
def test_encode_rejects_values_the_contract_refuses(bad: float) -> None:
    snap = _snap(3, ("Htot",))
    broken = m.TfSnapshot(
        seq=0, sim_time_s=0.0, batch_seq=0, freqs_hz=snap.freqs_hz, valid=snap.valid, estimates={"Htot": m.TransferFunction([1.0, bad, 2.0], [0.0] * 3)}
    )
    with pytest.raises(ValueError, match="finite and within"):
        encode_tf(broken)


@pytest.mark.parametrize(
    "changes,needle",
    [({"seq": -1}, "seq"), ({"batch_seq": 2**63}, "batch_seq"), ({"sim_time_s": -0.5}, "sim_time_s"), ({"wall_time_s": math.nan}, "wall_time_s")],
)
def test_encode_rejects_bad_header_fields(changes: dict[str, object], needle: str) -> None:
    snap = _snap(2)
    fields: dict[str, object] = {
        "seq": snap.seq,
        "sim_time_s": snap.sim_time_s,
        "wall_time_s": snap.wall_time_s,
        "batch_seq": snap.batch_seq,
        "freqs_hz": snap.freqs_hz,
        "valid": snap.valid,
        "estimates": snap.estimates,
    }
    fields.update(changes)
    with pytest.raises(ValueError, match=needle):
        encode_tf(m.TfSnapshot(**fields))  # type: ignore[arg-type]
