"""The plant's float/int fast paths give what the general paths give, value for value.

Each fast path of a co-simulated tick (plain floats and ints instead of
numpy on the 4-vectors, frames without python-can objects in the direct
wire, cached configuration) is compared here with the general path it
shortcuts, on inputs chosen to hit its edges."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from plant_emulator.canopen_node import CanopenNode
from plant_emulator.model import PlantConfig, RalfArm
from protocol.can_map import ConverterScale, NmtCommand, decode_analog_inputs_16, encode_nmt
from protocol.signals import ANALOG_INPUTS
from tests.plant.support import FakeApp

TPDO1 = 0x181


def _special_volts(scale: ConverterScale) -> list[float]:
    """Half-LSB boundaries and their neighbours, the ends, NaN, ±inf, ±0 and huge values."""
    lsb = scale.lsb_v
    out = [0.0, -0.0, math.nan, math.inf, -math.inf, 1e300, -1e300, scale.full_scale_v, -scale.full_scale_v]
    for k in (-(2 ** (scale.bits - 1)) - 1, -3, -1, 0, 1, 2, 7, 2 ** (scale.bits - 1) - 1, 2 ** (scale.bits - 1)):
        edge = (k + 0.5) * lsb
        out += [edge, math.nextafter(edge, math.inf), math.nextafter(edge, -math.inf)]
    return out


@pytest.mark.parametrize("bits", [12, 16, 20, 32])
def test_quantize_floats_equals_the_array_path(bits: int) -> None:
    scale = ConverterScale(bits)
    rng = np.random.default_rng(bits)
    values = _special_volts(scale) + (rng.standard_normal(2000) * 7.0).tolist() + (rng.uniform(-25, 25, 500)).tolist()
    counts, flags = scale.quantize_floats(values)
    reference = scale.quantize(np.array(values))  # > 8 values: numpy's rint/clip path
    assert len(values) > 8
    assert [type(c) for c in counts] == [int] * len(values) and [type(f) for f in flags] == [bool] * len(values)
    np.testing.assert_array_equal(np.array(counts, dtype=np.int64), reference.counts)
    np.testing.assert_array_equal(np.array(flags), reference.saturated)


def test_converter_constants_are_cached_and_right() -> None:
    scale = ConverterScale(12)
    assert scale.lsb_v == 20.0 / 4096 and scale.code_min == -2048 and scale.code_max == 2047
    assert scale.lsb_v is scale.lsb_v
    assert scale == ConverterScale(12) and hash(scale) == hash(ConverterScale(12))


@pytest.mark.parametrize("noise", [True, False])
def test_sensor_reading_arrays_are_its_lists(noise: bool) -> None:
    arm = RalfArm(PlantConfig(seed=3, sensor_noise=noise))
    arm.set_valve_voltages(np.array([2.0, -1.5]))
    vpu = np.array([ch.volts_per_unit for ch in ANALOG_INPUTS])
    centre = np.array([ch.centre for ch in ANALOG_INPUTS])
    for _ in range(50):
        arm.advance(0.005)
        r = arm.sample()
        assert r.codes.dtype == np.int64 and r.saturated.dtype == np.bool_
        np.testing.assert_array_equal(r.codes, r.code_list)
        np.testing.assert_array_equal(r.saturated, r.saturated_list)
        lsb = ConverterScale(r.bits).lsb_v
        np.testing.assert_array_equal(r.volts, r.codes.astype(np.float64) * lsb)
        np.testing.assert_array_equal(r.values_in, r.volts / vpu + centre)
        q = ConverterScale(r.bits).quantize(np.concatenate([r.analog_volts] * 3))  # the array path
        np.testing.assert_array_equal(q.counts[:4], r.codes)
        assert r.codes is r.codes  # made once, kept
    assert "codes=" in repr(r)


class _ListApp(FakeApp):
    """The same plant stand-in handing its codes as lists (as the plant service does)."""

    def on_sync(self, counter: int) -> tuple[list[int], list[bool]]:  # type: ignore[override]
        codes, sat = super().on_sync(counter)
        return codes.tolist(), sat.tolist()


class _FloatListApp(FakeApp):
    def on_sync(self, counter: int) -> tuple[list[float], list[bool]]:  # type: ignore[override]
        codes, sat = super().on_sync(counter)
        return [float(c) + 0.25 for c in codes.tolist()], sat.tolist()


def _tpdos(app: FakeApp, bits: int = 12) -> list[tuple[int, bytes]]:
    app.bits = bits
    node = CanopenNode(app)
    node.handle(can.Message(arbitration_id=0, data=encode_nmt(NmtCommand.START, 1), is_extended_id=False), 0.0)
    out = []
    for k in range(1, 6):
        app.saturated = np.array([k % 2 == 0, False, k == 3, False])
        frames = node.handle(can.Message(arbitration_id=0x80, data=bytes([k]), is_extended_id=False), 0.005 * k)
        out += [(f.arbitration_id, bytes(f.data)) for f in frames]
    return out


def test_the_node_takes_list_codes_as_it_takes_arrays() -> None:
    volts = (1.0, -2.5, 9.99, -10.0)
    reference = _tpdos(FakeApp(volts))
    assert _tpdos(_ListApp(volts)) == reference
    assert {cob for cob, _ in reference} == {TPDO1, 0x81}  # TPDO1s and the saturation EMCYs
    # floats in a list are not codes: the general path rounds them (+0.25 rounds away)
    assert _tpdos(_FloatListApp(volts)) == reference
    words = decode_analog_inputs_16(next(data for cob, data in reference if cob == TPDO1))
    np.testing.assert_array_equal(words >> 4, ConverterScale(12).quantize(np.array(volts)).counts)
