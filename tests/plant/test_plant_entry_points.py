"""The plant's public entry points that promise the same values as each
other: the converter's float and array quantization, a reading's arrays
and lists, ``sample_codes`` and ``sample``, the float and array valve
setters, the deferred latency tracker and
the plain one; and the block noise against numpy's own generator stream."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_emulator.model import PlantConfig, RalfArm
from protocol.can_map import ConverterScale
from protocol.signals import ANALOG_INPUTS


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


def test_block_normals_are_the_generators_stream() -> None:
    from plant_emulator.sensors import NOISE_BLOCK, BlockNormals

    reference = np.random.default_rng(11)
    blocked = BlockNormals(np.random.default_rng(11))
    drawn: list[float] = []
    expected: list[float] = []
    for k in range(3 * NOISE_BLOCK):
        if k % 97 == 5:
            drawn += blocked.standard_normal(7).tolist()  # other sizes, across block edges
            expected += reference.standard_normal(7).tolist()
        elif k % 101 == 3:
            drawn.append(blocked.standard_normal())
            expected.append(float(reference.standard_normal()))
        else:
            drawn += blocked.pair()
            expected += reference.standard_normal(2).tolist()
    assert drawn == expected


@pytest.mark.parametrize("capacity", [64, 65536])
def test_deferred_latency_reads_as_the_plain_tracker(capacity: int) -> None:
    from plant_emulator.service import DeferredLatency
    from service_kit.runtime import LatencyTracker

    plain, deferred = LatencyTracker(capacity), DeferredLatency(capacity)
    deferred.FLUSH_AT = 50  # flush inside the run too
    rng = np.random.default_rng(5)
    for k in range(3):
        for x in rng.exponential(1e-4, 37 + 71 * k).tolist():
            plain.add(x)
            deferred.add(x)
        assert deferred.count == plain.count
        np.testing.assert_array_equal(deferred.values(), plain.values())
        assert deferred.stats() == plain.stats()
    assert DeferredLatency().stats() == LatencyTracker().stats()


@pytest.mark.parametrize("noise", [True, False])
def test_sample_codes_are_the_readings_lists(noise: bool) -> None:
    """The SYNC path's codes (RalfArm.sample_codes, sensors.read_codes) are sample()'s, the same deviates drawn, through saturation."""
    a, b = RalfArm(PlantConfig(seed=5, sensor_noise=noise)), RalfArm(PlantConfig(seed=5, sensor_noise=noise))
    rng = np.random.default_rng(2)
    saturated = 0
    for k in range(400):
        v = np.array([10.0, -10.0]) if k < 150 else rng.uniform(-3.0, 3.0, 2)  # onto a stop: saturated channels
        for arm in (a, b):
            arm.set_valve_voltages(v)
            arm.advance(0.005)
        r = a.sample()
        codes, flags = b.sample_codes()
        assert codes == r.code_list and flags == r.saturated_list, k
        assert [type(c) for c in codes] == [int] * 4 and [type(f) for f in flags] == [bool] * 4
        saturated += any(flags)
    assert a.truth().as_dict() == b.truth().as_dict()
    assert saturated > 0


def test_output_values_are_set_as_the_output_array_is() -> None:
    """The node's float form of on_outputs (PlantApplication.on_output_values, RalfArm.set_valve_values) holds what the array form holds."""
    from plant_emulator.service import PlantApplication
    from protocol.settings import PlantSettings

    settings = PlantSettings(clock="lockstep", can_interface="virtual")
    by_array, by_values = PlantApplication(settings), PlantApplication(settings)
    for v0, v1 in ((0.0, -0.0), (9.995, -10.0), (12.5, -1e9), (3.25, 0.00488)):
        by_array.on_outputs(np.array([v0, v1]))
        by_values.on_output_values(v0, v1)
        assert by_values.arm._volts == by_array.arm._volts and [math.copysign(1, x) for x in by_values.arm._volts] == [
            math.copysign(1, x) for x in by_array.arm._volts
        ]
    with pytest.raises(ValueError, match="finite"):
        by_values.arm.set_valve_values(math.nan, 0.0)


def test_read_codes_quantizes_as_the_converter_at_the_rails() -> None:
    """read_codes' in-range shortcut and its loop give ConverterScale.quantize_floats' codes and flags at and around both rails, NaN and inf included."""
    from plant_emulator import sensors
    from protocol.can_map import ConverterScale

    for bits in (12, 16):
        scale = ConverterScale(bits)
        (v0, c0), (v1, c1), (v2, c2), (v3, c3) = sensors._MAPS
        hi, lsb = 2.0 * scale.full_scale_v, scale.lsb_v
        targets = [
            0.0,
            hi,
            -hi,
            math.nextafter(hi, 0.0),
            math.nextafter(-hi, 0.0),
            hi - 0.5 * lsb,
            -hi + 0.5 * lsb,
            (scale.code_max + 0.5) * lsb,
            1e9,
            math.nan,
            math.inf,
            -math.inf,
        ]
        for t in targets:
            for k in range(4):  # the target volts on one channel, the others at 0.1 V
                volts = [0.1] * 4
                volts[k] = t
                ext = (volts[0] / v0 + c0, volts[1] / v1 + c1)
                defl = (volts[2] / v2 + c2, volts[3] / v3 + c3)
                analog = [(ext[0] - c0) * v0, (ext[1] - c1) * v1, (defl[0] - c2) * v2, (defl[1] - c3) * v3]
                assert sensors.read_codes(ext, defl, (0.0, 0.0), scale, None) == scale.quantize_floats(analog), (bits, t, k)
