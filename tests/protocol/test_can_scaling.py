"""CAN map (protocol.can_map) and analog channel map (protocol.signals):
converter quantization and saturation, CiA 401 left-justified words, the
CANopen frames, the SYNC counter, and the thesis's resolutions in inches."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol import can_map as cm
from protocol import signals as sg
from protocol.errors import FrameError, ProtocolError

FAST = settings(max_examples=50, deadline=None)
BITS = [12, 16, 20]


def _scale(bits: int) -> cm.ConverterScale:
    return cm.ConverterScale(bits)


# --- converter scaling ---------------------------------------------------------------


def test_converter_constants() -> None:
    assert cm.ADC12.bits == cm.DAC12.bits == 12
    assert cm.ADC12.lsb_v == pytest.approx(4.8828125e-3, rel=0, abs=1e-15)
    assert (cm.ADC12.code_min, cm.ADC12.code_max) == (-2048, 2047)
    assert (_scale(16).code_min, _scale(16).code_max) == (-32768, 32767)
    assert (_scale(20).code_min, _scale(20).code_max) == (-(2**19), 2**19 - 1)
    assert cm.WORD16_VOLTS_PER_LSB == 10.0 / 32768
    assert cm.WORD32_VOLTS_PER_LSB == 10.0 / 2**31


@pytest.mark.parametrize("bits", [7, 33, 0, -12])
def test_converter_resolution_limits(bits: int) -> None:
    with pytest.raises(ValueError, match="8..32"):
        cm.ConverterScale(bits)


@pytest.mark.parametrize("full_scale", [0.0, -10.0])
def test_converter_full_scale_must_be_positive(full_scale: float) -> None:
    with pytest.raises(ValueError, match="full scale"):
        cm.ConverterScale(12, full_scale)


@pytest.mark.parametrize("bits", BITS)
@FAST
@given(data=st.data())
def test_quantization_error_at_most_half_an_lsb_inside_the_range(bits: int, data: st.DataObject) -> None:
    scale = _scale(bits)
    lo, hi = scale.code_min * scale.lsb_v, scale.code_max * scale.lsb_v
    volts = np.array(data.draw(st.lists(st.floats(min_value=lo, max_value=hi), min_size=1, max_size=16)))
    q = scale.quantize(volts)
    assert q.counts.dtype == np.int64 and q.counts.shape == volts.shape
    assert not q.saturated.any()
    err = np.abs(scale.to_volts(q.counts) - volts)
    assert np.all(err <= scale.lsb_v / 2 * (1 + 1e-9))


@pytest.mark.parametrize("bits", BITS)
def test_every_code_is_reproduced_exactly(bits: int) -> None:
    scale = _scale(bits)
    codes = np.arange(scale.code_min, scale.code_max + 1)
    q = scale.quantize(scale.to_volts(codes))
    np.testing.assert_array_equal(q.counts, codes)
    assert not q.saturated.any()


@pytest.mark.parametrize("bits", BITS)
def test_midpoints_round_to_a_neighbour(bits: int) -> None:
    scale = _scale(bits)
    codes = np.arange(scale.code_min, scale.code_max)
    q = scale.quantize((codes + 0.5) * scale.lsb_v)
    assert np.all((q.counts == codes) | (q.counts == codes + 1))


@pytest.mark.parametrize("bits", BITS)
@FAST
@given(volts=st.lists(st.floats(min_value=-1e6, max_value=1e6), min_size=2, max_size=16))
def test_quantization_is_monotonic(bits: int, volts: list[float]) -> None:
    v = np.sort(np.array(volts))
    assert np.all(np.diff(_scale(bits).quantize(v).counts) >= 0)


# values near the float maximum overflow to inf in ``v / lsb`` (a RuntimeWarning) before being clipped
@pytest.mark.filterwarnings("ignore:overflow encountered in divide:RuntimeWarning")
@pytest.mark.parametrize("bits", BITS)
@FAST
@given(data=st.data())
def test_out_of_range_clipped_to_the_end_codes_and_flagged(bits: int, data: st.DataObject) -> None:
    scale = _scale(bits)
    above = data.draw(st.floats(min_value=(scale.code_max + 0.5) * scale.lsb_v * (1 + 1e-12), max_value=1.7e308))
    below = data.draw(st.floats(max_value=(scale.code_min - 0.5) * scale.lsb_v * (1 + 1e-12), min_value=-1.7e308))
    q = scale.quantize([above, below])
    np.testing.assert_array_equal(q.counts, [scale.code_max, scale.code_min])
    np.testing.assert_array_equal(q.saturated, [True, True])


@pytest.mark.filterwarnings("ignore:overflow encountered in divide:RuntimeWarning")
@pytest.mark.parametrize("bits", BITS)
def test_full_scale_ends(bits: int) -> None:
    scale = _scale(bits)
    q = scale.quantize([10.0, -10.0, 10.5, -10.5, 1e300, -1e300])
    np.testing.assert_array_equal(q.counts, [scale.code_max, scale.code_min, scale.code_max, scale.code_min, scale.code_max, scale.code_min])
    # +10 V is one LSB beyond the top code (flagged); -10 V is exactly the bottom code (not flagged)
    np.testing.assert_array_equal(q.saturated, [True, False, True, True, True, True])


@pytest.mark.parametrize("bits", BITS)
def test_nan_is_flagged_and_yields_a_valid_code(bits: int) -> None:
    scale = _scale(bits)
    q = scale.quantize([math.nan, 1.0, -math.nan])
    np.testing.assert_array_equal(q.saturated, [True, False, True])
    assert q.counts[0] == 0 and q.counts[2] == 0  # documented: NaN -> flagged, code 0
    assert scale.code_min <= q.counts.min() and q.counts.max() <= scale.code_max


@pytest.mark.parametrize("bits", BITS)
def test_infinities_are_flagged(bits: int) -> None:
    q = _scale(bits).quantize([math.inf, -math.inf])
    np.testing.assert_array_equal(q.saturated, [True, True])


@pytest.mark.parametrize("bits", BITS)
def test_infinities_clip_to_the_end_codes(bits: int) -> None:
    scale = _scale(bits)
    q = scale.quantize([math.inf, -math.inf])
    np.testing.assert_array_equal(q.counts, [scale.code_max, scale.code_min])


def test_quantize_scalar_and_shape() -> None:
    q = cm.ADC12.quantize(1.0)
    assert q.counts.shape == () and int(q.counts) == 205 and not bool(q.saturated)
    q2 = cm.ADC12.quantize(np.zeros((3, 4)))
    assert q2.counts.shape == (3, 4) and q2.saturated.shape == (3, 4)


# --- left-justified words ------------------------------------------------------------


@pytest.mark.parametrize("bits,word_bits", [(12, 16), (16, 16), (12, 32), (16, 32), (20, 32), (8, 16), (32, 32)])
def test_left_justify_round_trip_every_code(bits: int, word_bits: int) -> None:
    scale = _scale(bits)
    if bits <= 20:
        codes = np.arange(scale.code_min, scale.code_max + 1)
    else:
        codes = np.array([scale.code_min, -1, 0, 1, scale.code_max])
    words = scale.left_justify(codes, word_bits)
    assert words.min() >= -(2 ** (word_bits - 1)) and words.max() <= 2 ** (word_bits - 1) - 1
    assert np.all(words % (1 << (word_bits - bits)) == 0)  # padding bits are zero
    np.testing.assert_array_equal(scale.from_left_justified(words, word_bits), codes)
    # any value of the padding bits is discarded
    pad = (1 << (word_bits - bits)) - 1
    np.testing.assert_array_equal(scale.from_left_justified(words | pad, word_bits), codes)


@pytest.mark.parametrize("bits", [12, 16])
def test_left_justified_int16_reads_as_volts_whatever_the_resolution(bits: int) -> None:
    scale = _scale(bits)
    codes = np.arange(scale.code_min, scale.code_max + 1)
    np.testing.assert_array_equal(scale.left_justify(codes) * cm.WORD16_VOLTS_PER_LSB, scale.to_volts(codes))


@pytest.mark.parametrize("bits", [12, 16, 20])
def test_left_justified_int32_reads_as_volts_whatever_the_resolution(bits: int) -> None:
    scale = _scale(bits)
    codes = np.array([scale.code_min, -1, 0, 1, 12345 % scale.code_max, scale.code_max])
    np.testing.assert_allclose(scale.left_justify(codes, 32) * cm.WORD32_VOLTS_PER_LSB, scale.to_volts(codes), rtol=1e-15, atol=0)


def test_twenty_bits_do_not_fit_a_16_bit_word() -> None:
    with pytest.raises(ValueError, match="does not fit"):
        _scale(20).left_justify([0])
    with pytest.raises(ValueError, match="does not fit"):
        _scale(20).from_left_justified([0])
    assert _scale(20).shift(32) == 12 and cm.ADC12.shift(16) == 4


# --- frames --------------------------------------------------------------------------


def test_cob_ids() -> None:
    ids = cm.cob_ids()
    assert ids == {
        "nmt": 0x000,
        "sync": 0x080,
        "emcy": 0x081,
        "tpdo1": 0x181,
        "tpdo2": 0x281,
        "tpdo3": 0x381,
        "rpdo1": 0x201,
        "sdo_tx": 0x581,
        "sdo_rx": 0x601,
        "heartbeat": 0x701,
    }
    for node in (1, 42, 127):
        node_ids = cm.cob_ids(node)
        assert len(set(node_ids.values())) == len(node_ids)
        assert all(0 <= cob <= 0x7FF for cob in node_ids.values())  # 11-bit identifiers
        assert node_ids["heartbeat"] == 0x700 + node


@pytest.mark.parametrize("node", [0, 128, -1])
def test_cob_ids_reject_bad_node_ids(node: int) -> None:
    with pytest.raises(ValueError, match="1..127"):
        cm.cob_ids(node)


def _wrong_lengths(expected: int) -> list[bytes]:
    return [bytes(range(n)) for n in range(0, 17) if n != expected]


int16 = st.integers(-(2**15), 2**15 - 1)
int32 = st.integers(-(2**31), 2**31 - 1)


@FAST
@given(words=st.lists(int16, min_size=4, max_size=4))
def test_tpdo1_round_trip(words: list[int]) -> None:
    payload = cm.encode_analog_inputs_16(words)
    assert len(payload) == 8
    back = cm.decode_analog_inputs_16(payload)
    assert back.dtype == np.int64
    np.testing.assert_array_equal(back, words)
    np.testing.assert_array_equal(cm.decode_analog_inputs_16(bytearray(payload)), words)


def test_tpdo1_little_endian_layout() -> None:
    assert cm.encode_analog_inputs_16([1, -1, 0x1234, -32768]) == bytes.fromhex("0100ffff34120080")


@FAST
@given(words=st.lists(int32, min_size=4, max_size=4))
def test_tpdo2_tpdo3_round_trip(words: list[int]) -> None:
    tpdo2, tpdo3 = cm.encode_analog_inputs_32(words)
    assert len(tpdo2) == len(tpdo3) == 8
    np.testing.assert_array_equal(np.concatenate([cm.decode_analog_inputs_32(tpdo2), cm.decode_analog_inputs_32(tpdo3)]), words)


@FAST
@given(words=st.lists(int16, min_size=2, max_size=2))
def test_rpdo1_round_trip(words: list[int]) -> None:
    payload = cm.encode_analog_outputs(words)
    assert len(payload) == 4
    np.testing.assert_array_equal(cm.decode_analog_outputs(payload), words)


@pytest.mark.parametrize(
    "encode,shape",
    [(cm.encode_analog_inputs_16, 4), (cm.encode_analog_inputs_32, 4), (cm.encode_analog_outputs, 2)],
    ids=["tpdo1", "tpdo2/3", "rpdo1"],
)
def test_pdo_encoders_reject_wrong_channel_counts(encode, shape: int) -> None:  # type: ignore[no-untyped-def]
    for bad in ([0] * (shape - 1), [0] * (shape + 1), [[0] * shape], 0):
        with pytest.raises(ValueError, match="carr"):
            encode(bad)


@pytest.mark.parametrize(
    "decode,expected,name",
    [
        (cm.decode_analog_inputs_16, 8, "TPDO1"),
        (cm.decode_analog_inputs_32, 8, "TPDO2/3"),
        (cm.decode_analog_outputs, 4, "RPDO1"),
        (cm.decode_sync, 1, "SYNC"),
        (cm.decode_nmt, 2, "NMT"),
        (cm.decode_heartbeat, 1, "heartbeat"),
        (cm.decode_emcy, 8, "EMCY"),
    ],
    ids=lambda x: x if isinstance(x, str) else None,
)
def test_wrong_length_frames_raise_frame_error(decode, expected: int, name: str) -> None:  # type: ignore[no-untyped-def]
    for data in _wrong_lengths(expected):
        with pytest.raises(FrameError, match=f"{name}: expected {expected} data bytes, got {len(data)}"):
            decode(data)


def test_frame_error_is_a_protocol_error() -> None:
    assert issubclass(FrameError, ProtocolError)


@pytest.mark.parametrize(
    "decode",
    [cm.decode_analog_inputs_16, cm.decode_analog_inputs_32, cm.decode_analog_outputs, cm.decode_sync, cm.decode_nmt, cm.decode_heartbeat, cm.decode_emcy],
)
@settings(max_examples=150, deadline=None)
@given(data=st.binary(max_size=10))
def test_frame_decoders_raise_only_frame_error(decode, data: bytes) -> None:  # type: ignore[no-untyped-def]
    try:
        decode(data)
    except FrameError:
        pass


@pytest.mark.parametrize("command", list(cm.NmtCommand))
def test_nmt_round_trip(command: cm.NmtCommand) -> None:
    for node in (0, 1, 64, 127):
        payload = cm.encode_nmt(command, node)
        assert payload == bytes([command.value, node])
        assert cm.decode_nmt(payload) == (command, node)
        assert isinstance(cm.decode_nmt(payload)[0], cm.NmtCommand)


def test_nmt_rejects_bad_commands_and_nodes() -> None:
    valid = {c.value for c in cm.NmtCommand}
    for byte in range(256):
        if byte not in valid:
            with pytest.raises(FrameError, match="unknown NMT command"):
                cm.decode_nmt(bytes([byte, 1]))
    for node in range(128, 256):
        with pytest.raises(FrameError, match="node id"):
            cm.decode_nmt(bytes([cm.NmtCommand.START, node]))
    for node in (-1, 128):
        with pytest.raises(ValueError, match="0..127"):
            cm.encode_nmt(cm.NmtCommand.START, node)


@pytest.mark.parametrize("state", list(cm.NmtState))
def test_heartbeat_round_trip(state: cm.NmtState) -> None:
    assert cm.decode_heartbeat(cm.encode_heartbeat(state)) is state
    assert cm.decode_heartbeat(bytes([state.value | 0x80])) is state  # toggle bit ignored


def test_heartbeat_rejects_unknown_states() -> None:
    valid = {s.value for s in cm.NmtState}
    for byte in range(256):
        if byte & 0x7F not in valid:
            with pytest.raises(FrameError, match="unknown heartbeat state"):
                cm.decode_heartbeat(bytes([byte]))


@FAST
@given(code=st.integers(0, 0xFFFF), register=st.integers(0, 0xFF), vendor=st.binary(max_size=5))
def test_emcy_round_trip(code: int, register: int, vendor: bytes) -> None:
    payload = cm.encode_emcy(code, register, vendor)
    assert len(payload) == 8
    emcy = cm.decode_emcy(payload)
    assert (emcy.code, emcy.register, emcy.vendor) == (code, register, vendor.ljust(5, b"\x00"))


def test_emcy_details() -> None:
    payload = cm.encode_emcy(cm.EmcyCode.OUTPUT_CLIPPED, vendor=b"\x03")
    assert payload == bytes.fromhex("1023010300000000")
    emcy = cm.decode_emcy(payload)
    assert emcy.name == "OUTPUT_CLIPPED" and emcy.register == 1
    assert cm.decode_emcy(cm.encode_emcy(0x1234)).name == "0x1234"
    for code in cm.EmcyCode:
        assert cm.decode_emcy(cm.encode_emcy(code)).name == code.name
    assert cm.decode_emcy(cm.encode_emcy(0, register=0x1FF)).register == 0xFF
    with pytest.raises(ValueError, match="5 vendor bytes"):
        cm.encode_emcy(cm.EmcyCode.JOINT_LIMIT, vendor=b"123456")


# --- SYNC ----------------------------------------------------------------------------


def test_sync_round_trip_every_counter() -> None:
    for counter in range(1, 241):
        assert cm.encode_sync(counter) == bytes([counter])
        assert cm.decode_sync(cm.encode_sync(counter)) == counter


def test_sync_rejects_counters_outside_1_to_240() -> None:
    for counter in (0, *range(241, 256)):
        with pytest.raises(FrameError, match="outside 1..240"):
            cm.decode_sync(bytes([counter]))
    for counter in (0, 241, -1, 256):
        with pytest.raises(ValueError, match="1..240"):
            cm.encode_sync(counter)


def test_sync_counter_wraps_240_to_1() -> None:
    assert cm.SYNC_COUNTER_OVERFLOW == 240
    assert cm.next_sync_counter(240) == 1
    assert cm.next_sync_counter(1) == 2
    assert cm.next_sync_counter(239) == 240
    counter, seen = 1, []
    for _ in range(480):
        seen.append(counter)
        counter = cm.next_sync_counter(counter)
    assert seen == list(range(1, 241)) * 2


def _advance(counter: int, steps: int) -> int:
    for _ in range(steps):
        counter = cm.next_sync_counter(counter)
    return counter


@settings(max_examples=200, deadline=None)
@given(start=st.integers(1, 240), missed=st.integers(0, 238))
def test_sync_gap_counts_missed_syncs(start: int, missed: int) -> None:
    assert cm.sync_gap(start, _advance(start, missed + 1)) == missed


def test_sync_gap_examples() -> None:
    assert cm.sync_gap(1, 2) == 0
    assert cm.sync_gap(240, 1) == 0
    assert cm.sync_gap(239, 1) == 1
    assert cm.sync_gap(240, 3) == 2
    assert cm.sync_gap(10, 15) == 4


# --- valve output frames -------------------------------------------------------------


@FAST
@given(volts=st.lists(st.floats(min_value=-10.0, max_value=10.0 - cm.DAC12.lsb_v), min_size=2, max_size=2))
def test_output_frame_round_trip(volts: list[float]) -> None:
    payload, clipped = cm.volts_to_output_frame(volts)
    assert len(payload) == 4 and not clipped.any()
    back = cm.output_frame_to_volts(payload)
    assert np.all(np.abs(back - volts) <= cm.DAC12.lsb_v / 2 * (1 + 1e-9))
    # the raw INT16 words read as volts with the DBC factor
    np.testing.assert_array_equal(cm.decode_analog_outputs(payload) * cm.WORD16_VOLTS_PER_LSB, back)


def test_output_frame_clips_and_flags() -> None:
    payload, clipped = cm.volts_to_output_frame([12.0, -12.0])
    np.testing.assert_array_equal(clipped, [True, True])
    np.testing.assert_allclose(cm.output_frame_to_volts(payload), [2047 * cm.DAC12.lsb_v, -10.0])
    payload, clipped = cm.volts_to_output_frame([math.nan, 0.0])
    np.testing.assert_array_equal(clipped, [True, False])
    np.testing.assert_array_equal(cm.output_frame_to_volts(payload), [0.0, 0.0])


def test_output_frame_with_a_16_bit_dac() -> None:
    dac16 = cm.ConverterScale(16)
    payload, clipped = cm.volts_to_output_frame([1.0, -3.0], dac16)
    back = cm.output_frame_to_volts(payload, dac16)
    assert np.all(np.abs(back - [1.0, -3.0]) <= dac16.lsb_v / 2) and not clipped.any()


def test_output_frame_needs_two_channels() -> None:
    with pytest.raises(ValueError):
        cm.volts_to_output_frame([1.0, 2.0, 3.0])


# --- analog channel map (signals) ----------------------------------------------------


def test_channel_order_and_ranges() -> None:
    assert [ch.name for ch in sg.ANALOG_INPUTS] == ["cylinder1_extension", "cylinder2_extension", "link1_deflection", "link2_deflection"]
    assert [ch.name for ch in sg.ANALOG_OUTPUTS] == ["valve1", "valve2"]
    assert len(sg.ANALOG_INPUTS) == cm.N_ANALOG_INPUTS and len(sg.ANALOG_OUTPUTS) == cm.N_ANALOG_OUTPUTS
    assert sg.CYLINDER1_EXTENSION.range == pytest.approx((0.0, 20.0))
    assert sg.CYLINDER2_EXTENSION.range == pytest.approx((0.0, 20.0))
    assert sg.LINK1_DEFLECTION.range == pytest.approx((-0.575, 0.575))
    assert sg.LINK2_DEFLECTION.range == pytest.approx((-0.555, 0.555))
    assert sg.VALVE1.range == pytest.approx((-10.0, 10.0))
    for ch in (*sg.ANALOG_INPUTS, *sg.ANALOG_OUTPUTS):
        lo, hi = ch.range
        np.testing.assert_allclose(ch.to_volts([lo, ch.centre, hi]), [-10.0, 0.0, 10.0], atol=1e-12)


@pytest.mark.parametrize("channel", [*sg.ANALOG_INPUTS, *sg.ANALOG_OUTPUTS], ids=lambda c: c.name)
@FAST
@given(data=st.data())
def test_volts_engineering_round_trip(channel: sg.AnalogChannel, data: st.DataObject) -> None:
    lo, hi = channel.range
    values = np.array(data.draw(st.lists(st.floats(min_value=lo, max_value=hi), min_size=1, max_size=8)))
    np.testing.assert_allclose(channel.from_volts(channel.to_volts(values)), values, rtol=1e-12, atol=1e-12 * (hi - lo))
    volts = np.array(data.draw(st.lists(st.floats(min_value=-10.0, max_value=10.0), min_size=1, max_size=8)))
    np.testing.assert_allclose(channel.to_volts(channel.from_volts(volts)), volts, rtol=1e-12, atol=1e-12)


@FAST
@given(values=st.tuples(st.floats(0, 20), st.floats(0, 20), st.floats(-0.575, 0.575), st.floats(-0.555, 0.555)))
def test_four_inputs_round_trip(values: tuple[float, float, float, float]) -> None:
    volts = sg.inputs_to_volts(values)
    assert volts.shape == (4,) and np.all(np.abs(volts) <= 10.0 + 1e-9)
    np.testing.assert_allclose(sg.volts_to_inputs(volts), values, atol=1e-12)


@pytest.mark.parametrize("bad", [[0.0] * 3, [0.0] * 5])
def test_four_inputs_required(bad: list[float]) -> None:
    with pytest.raises(ValueError):
        sg.inputs_to_volts(bad)
    with pytest.raises(ValueError):
        sg.volts_to_inputs(bad)


def _lsb_in(channel: sg.AnalogChannel, scale: cm.ConverterScale = cm.ADC12) -> float:
    return scale.lsb_v / channel.volts_per_unit


def test_lsb_in_inches_matches_the_thesis() -> None:
    # cylinders: 4.88e-3 in, which the thesis quotes to one figure as 5e-3 in
    for ch in (sg.CYLINDER1_EXTENSION, sg.CYLINDER2_EXTENSION):
        assert _lsb_in(ch) == pytest.approx(4.8828125e-3, rel=1e-12)
        assert f"{_lsb_in(ch):.0e}" == "5e-03"
        assert _lsb_in(ch) == pytest.approx(5e-3, rel=0.025)
    # deflections: within 2 % of the thesis's 2.8e-4 and 2.7e-4 in
    assert _lsb_in(sg.LINK1_DEFLECTION) == pytest.approx(2.8e-4, rel=0.02)
    assert _lsb_in(sg.LINK2_DEFLECTION) == pytest.approx(2.7e-4, rel=0.02)
    assert f"{_lsb_in(sg.LINK1_DEFLECTION):.1e}" == "2.8e-04"
    assert f"{_lsb_in(sg.LINK2_DEFLECTION):.1e}" == "2.7e-04"


@settings(max_examples=100, deadline=None)
@given(values=st.tuples(st.floats(0.01, 19.99), st.floats(0.01, 19.99), st.floats(-0.57, 0.57), st.floats(-0.55, 0.55)))
def test_adc_path_end_to_end(values: tuple[float, float, float, float]) -> None:
    """Engineering value -> volts -> 12-bit code -> TPDO1 -> code -> volts ->
    engineering value: the error is at most half an LSB in inches."""
    q = cm.ADC12.quantize(sg.inputs_to_volts(values))
    assert not q.saturated.any()
    payload = cm.encode_analog_inputs_16(cm.ADC12.left_justify(q.counts))
    volts = cm.ADC12.to_volts(cm.ADC12.from_left_justified(cm.decode_analog_inputs_16(payload)))
    back = sg.volts_to_inputs(volts)
    half_lsb = np.array([_lsb_in(ch) for ch in sg.ANALOG_INPUTS]) / 2
    assert np.all(np.abs(back - values) <= half_lsb * (1 + 1e-9))


@settings(max_examples=50, deadline=None)
@given(values=st.tuples(st.floats(0.01, 19.99), st.floats(0.01, 19.99), st.floats(-0.57, 0.57), st.floats(-0.55, 0.55)))
def test_adc_path_end_to_end_20_bits(values: tuple[float, float, float, float]) -> None:
    adc20 = cm.ConverterScale(20)
    q = adc20.quantize(sg.inputs_to_volts(values))
    tpdo2, tpdo3 = cm.encode_analog_inputs_32(adc20.left_justify(q.counts, 32))
    words = np.concatenate([cm.decode_analog_inputs_32(tpdo2), cm.decode_analog_inputs_32(tpdo3)])
    back = sg.volts_to_inputs(words * cm.WORD32_VOLTS_PER_LSB)
    half_lsb = np.array([_lsb_in(ch, adc20) for ch in sg.ANALOG_INPUTS]) / 2
    assert np.all(np.abs(back - values) <= half_lsb * (1 + 1e-9))
