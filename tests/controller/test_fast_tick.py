"""The controller's per-tick forms on plain numbers equal the array forms bit
for bit: the law's row (engineering [A.7, A.8], OATF [3-34], PI, 12-bit D/A)
against a reference assembled from the numpy APIs (``PinTriangle.angle``,
``AnalogChannel.from_volts``, ``OatfFilter.step``, ``PIController.step_vectorised``,
``ConverterScale.quantize`` on arrays); the record's row append against the
mapping append; the TPDO1/RPDO1 codecs and the D/A quantizer against
``protocol.can_map``'s array codecs."""

from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest

from controller.config import build_trajectory, law_config
from controller.engineering import measure, measure_values
from controller.excitation import dither_table
from controller.loop import ROW_DEFLECTIONS, ROW_NAMES, ROW_VOLTS, ControlLaw
from controller.oatf import OatfConfig, OatfFilter, StageDesign, cascade_kernel, design_stage
from controller.pi import PIController
from controller.record import ROW_BLOCK, ChunkedRecord, ColumnBuffer, RowCounter
from protocol import can_map, geometry
from protocol.settings import ControllerSettings
from protocol.signals import ANALOG_INPUTS


def _bits(values: list[Any]) -> list[Any]:
    """Values compared by their IEEE bits (NaN equal to itself, -0.0 not 0.0)."""
    return [struct.pack("<d", v) if isinstance(v, float) else v for v in values]


def _reference_measure(w: list[int]) -> tuple[float, ...]:
    volts = [x * can_map.WORD16_VOLTS_PER_LSB for x in w]
    values = [float(ch.from_volts(v)) for ch, v in zip(ANALOG_INPUTS, volts, strict=True)]
    t1, t2 = (float(c.angle(values[i])) for i, c in enumerate(geometry.CYLINDERS))
    p1, p2 = (float(p) for p in geometry.theta_to_phi(t1, t2))
    return (*volts, values[0], values[1], values[2], values[3], t1, t2, p1, p2)


def test_measure_values_is_the_array_reference() -> None:
    rng = np.random.default_rng(3)
    words = rng.integers(-32768, 32768, size=(4000, 4)).tolist() + [[-32768] * 4, [32767] * 4, [0] * 4]
    for w in words:
        assert _bits(list(measure_values(w))) == _bits(list(_reference_measure(w)))
        m = measure(np.array(w))
        v = measure_values(w)
        assert m.volts.tolist() == list(v[:4]) and m.theta_rad.tolist() == list(v[8:10]) and m.phi_rad.tolist() == list(v[10:12])


class _ReferenceLaw:
    """The law as the array forms compute it (thesis §4: set-point -> OATF -> PI -> OATF -> D/A)."""

    def __init__(self, law: ControlLaw) -> None:
        self.law = law
        cfg = law.config
        self.pi = PIController(law.pi.config)
        self.oatf = None
        if law.oatf is not None:
            self.oatf = OatfFilter([cfg.oatf_frequency_hz], n_channels=2, config=cfg.oatf, initial=law.setpoints[0] if cfg.oatf_location == "outer" else 0.0)

    def row(self, tick: int, w: list[int]) -> list[Any]:
        v0, v1, v2, v3, e0, e1, d0, d1, t1, t2, p1, p2 = _reference_measure(w)
        ref = np.asarray(self.law.setpoints[tick % self.law.lap_ticks], dtype=np.float64)
        shaped = ref
        outer = self.law.config.oatf_location == "outer"
        if self.oatf is not None and outer:
            shaped = self.oatf.step(ref)
        u = self.pi.step_vectorised(np.asarray(shaped) - np.array([p1, p2]))
        if self.oatf is not None and not outer:
            u = np.clip(self.oatf.step(u), -can_map.DAC12.full_scale_v, can_map.DAC12.full_scale_v)
        d = self.law.config.dither
        if d.enabled:  # the dither before the D/A (controller.excitation)
            table = dither_table(d, self.law.config.sample_period_s)
            q = can_map.DAC12.quantize(np.concatenate([u + table[tick % len(table)], np.zeros(8)]))
        else:
            q = can_map.DAC12.quantize(np.concatenate([u, np.zeros(8)]))  # > 8 values: numpy's own path
        volts = can_map.DAC12.to_volts(q.counts[:2])
        return [
            tick * self.law.config.sample_period_s,
            *ref.tolist(),
            *np.asarray(shaped).tolist(),
            p1,
            p2,
            t1,
            t2,
            e0,
            e1,
            d0,
            d1,
            *w,
            v0,
            v1,
            v2,
            v3,
            *volts.tolist(),
            *u.tolist(),
        ]


@pytest.mark.parametrize(
    "settings",
    [
        {"oatf_mode": "adaptive"},
        {"oatf_mode": "fixed", "oatf": {"location": "inner"}},
        {"oatf_mode": "off"},
        {"oatf_mode": "adaptive", "oatf": {"max_stages": 3}},
        {"oatf_mode": "off", "dither": {"amplitude_v": 0.3}},
        {"oatf_mode": "fixed", "oatf": {"location": "inner"}, "dither": {"amplitude_v": 0.5, "seed": 9}},
    ],
)
def test_step_row_is_the_array_reference(settings: dict[str, Any]) -> None:
    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", **settings)
    law = ControlLaw(law_config(cs), build_trajectory(cs))
    ref = _ReferenceLaw(law)
    rng = np.random.default_rng(7)
    centre = [int(x) for x in can_map.decode_analog_inputs_16(can_map.encode_analog_inputs_16([9000, 9000, 0, 0]))]
    for tick in range(600):
        w = [int(c + d) for c, d in zip(centre, rng.integers(-3000, 3000, size=4), strict=True)]
        if tick == 300 and law.oatf is not None:  # a redesign mid-run (two stages where allowed)
            freqs = [3.1, 7.7][: law.oatf.config.max_stages]
            law.oatf.update_modes(freqs)
            assert ref.oatf is not None
            ref.oatf.update_modes(freqs)
        row = law.step_row(tick, w)
        assert len(row) == len(ROW_NAMES)
        assert _bits(row) == _bits(ref.row(tick, w)), tick
        assert row[ROW_VOLTS : ROW_VOLTS + 2] == row[ROW_NAMES.index("u1_v") : ROW_NAMES.index("u2_v") + 1]
        assert row[ROW_DEFLECTIONS] == row[ROW_NAMES.index("defl1_in")]


def test_step_and_record_row_are_built_from_step_row() -> None:
    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", oatf_mode="adaptive")
    a = ControlLaw(law_config(cs), build_trajectory(cs))
    b = ControlLaw(law_config(cs), build_trajectory(cs))
    for tick in range(50):
        w = [9000 + tick, 8000 - tick, 100, -100]
        rec = a.record_row(tick, a.step(tick, np.array(w)))
        row = b.step_row(tick, w)
        assert [rec[name] for name in ROW_NAMES] == row and rec["tick"] == tick


def test_oatf_step_values_equals_step_for_every_cascade() -> None:
    rng = np.random.default_rng(5)
    for freqs in ([4.4], [3.0, 9.5], [2.5, 6.0, 11.0]):
        cfg = OatfConfig(max_stages=len(freqs))
        a = OatfFilter(freqs, n_channels=2, config=cfg, initial=0.3)
        b = OatfFilter(freqs, n_channels=2, config=cfg, initial=0.3)
        for k in range(1000):
            x = rng.normal(size=2)
            assert a.step(x).tolist() == b.step_values(x.tolist())
            if k == 500:
                a.update_modes([f * 1.1 for f in freqs])
                b.update_modes([f * 1.1 for f in freqs])


def test_one_stage_kernel_is_the_convolution() -> None:
    for f in (1.5, 4.4, 9.9, 19.0):
        stage = design_stage(f, 0.09, 0.005)
        delays, weights = cascade_kernel([stage])
        n = stage.delay_samples
        poly = np.zeros(2 * n + 1)
        poly[[0, n, 2 * n]] = stage.coefficients
        dense = np.convolve(np.ones(1), poly)
        assert delays.tolist() == np.flatnonzero(dense).tolist() and weights.tolist() == dense[np.flatnonzero(dense)].tolist()
    zero_middle = StageDesign(4.0, 0.0, 3, 0.005, (0.5, 0.0, 0.5))
    delays, weights = cascade_kernel([zero_middle])
    assert delays.tolist() == [0, 6] and weights.tolist() == [0.5, 0.5]


def test_quantizer_and_codecs_match_the_array_forms() -> None:
    rng = np.random.default_rng(11)
    values = rng.normal(scale=12.0, size=20000).tolist() + [math.nan, math.inf, -math.inf, 10.0, -10.0, 1e300, -0.0]
    values += [k * can_map.DAC12.lsb_v + 0.5 * can_map.DAC12.lsb_v for k in range(-2100, 2100, 7)]  # halves: round to even
    codes, flags = can_map.DAC12_VALUES(values)
    q = can_map.DAC12.quantize(np.array(values))
    assert codes == q.counts.tolist() and flags == q.saturated.tolist()
    for _ in range(500):
        words = rng.integers(-32768, 32768, size=4).tolist()
        data = can_map.encode_analog_inputs_16(words)
        assert list(can_map.decode_analog_inputs_16_values(data)) == can_map.decode_analog_inputs_16(data).tolist()
        w0, w1 = (int(x) for x in rng.integers(-32768, 32768, size=2))
        assert can_map.encode_analog_outputs_values(w0, w1) == can_map.encode_analog_outputs([w0, w1])
    with pytest.raises(can_map.FrameError):
        can_map.decode_analog_inputs_16_values(b"\x00" * 7)
    with pytest.raises(ValueError):
        can_map.encode_analog_outputs_values(40000, 0)


def test_append_row_stores_what_append_stores(tmp_path: Any) -> None:
    columns = {"a": np.float64, "b": np.float64, "flag": np.bool_, "tick": np.int64}
    by_row, by_map = ColumnBuffer(columns, capacity=16), ColumnBuffer(columns, capacity=16)
    chunked = ChunkedRecord(tmp_path / "r", columns, chunk_rows=700)
    counter = RowCounter(columns)
    rng = np.random.default_rng(2)
    n = 3 * ROW_BLOCK + 17
    for i in range(n):
        row = [float(rng.normal()), math.nan if i % 97 == 0 else i * 0.5, i % 3 == 0, i]
        if i == ROW_BLOCK + 5:
            by_row.append(dict(zip(columns, row, strict=True)))  # a mapping between rows keeps the order
        else:
            by_row.append_row(row)
        by_map.append(dict(zip(columns, row, strict=True)))
        chunked.append_row(row)
        counter.append_row(row)
        if i == 100:
            assert len(by_row) == 101 and by_row.column("tick").tolist() == list(range(101))
    assert len(by_row) == len(by_map) == len(chunked) == len(counter) == n
    got, want, streamed = by_row.to_columns(), by_map.to_columns(), chunked.to_columns()
    for name in columns:
        assert got[name].dtype == want[name].dtype == streamed[name].dtype
        assert got[name].tobytes() == want[name].tobytes() == streamed[name].tobytes()
    chunked.close()
    with pytest.raises(ValueError, match="one per column"):
        by_row.append_row([1.0, 2.0])
    by_row.clear()
    assert len(by_row) == 0


@pytest.mark.parametrize(
    "settings",
    [
        {"oatf_mode": "adaptive"},
        {"oatf_mode": "fixed", "oatf": {"location": "inner"}},
        {"oatf_mode": "off"},
        {"oatf_mode": "adaptive", "oatf": {"max_stages": 3}},
        {"oatf_mode": "off", "dither": {"amplitude_v": 0.3}},
        {"oatf_mode": "fixed", "oatf": {"location": "inner"}, "dither": {"amplitude_v": 0.5, "seed": 9}},
    ],
)
def test_compiled_tick_is_the_python_form(settings: dict[str, Any]) -> None:
    """controller/fast_tick.py's one compiled call against ``ControlLaw._compute``
    (itself tested against the array forms above): the row, the D/A codes and
    their flags, and the state both leave (the OATF's delay line and head, the
    PI's integrator and terms), over words that saturate the D/A and cut the
    integrator, through a redesign and across a lap's end."""
    from controller import fast_tick

    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", **settings)
    a = ControlLaw(law_config(cs), build_trajectory(cs))
    b = ControlLaw(law_config(cs), build_trajectory(cs))
    assert a.compiled and fast_tick.sum_matches()
    rng = np.random.default_rng(11)
    for n, tick in enumerate([*range(400), *range(a.lap_ticks - 50, a.lap_ticks + 50)]):
        spread = 200 if n % 3 else 20000  # small errors (the integrator admits them) and wild ones (D/A saturates)
        w = [int(x) for x in np.clip(np.array([9000, 9000, 0, 0]) + rng.integers(-spread, spread, size=4), -32768, 32767)]
        if n == 200 and a.oatf is not None and b.oatf is not None:
            freqs = [3.1, 7.7][: a.oatf.config.max_stages]
            a.oatf.update_modes(freqs)
            b.oatf.update_modes(freqs)
        a.tick_compiled(tick, *w)
        row = a.row.tolist()
        ref, s0, s1 = b._compute(tick, w)
        assert _bits(row) == _bits([float(x) for x in ref]), tick
        codes = [round(ref[ROW_VOLTS] / can_map.DAC12.lsb_v), round(ref[ROW_VOLTS + 1] / can_map.DAC12.lsb_v)]
        assert a.codes.tolist() == [*codes, int(s0), int(s1)]
        assert _bits(a.pi.state.tolist()) == _bits(b.pi.state.tolist())
        if a.oatf is not None and b.oatf is not None:
            assert a.oatf._head == b.oatf._head and np.array_equal(a.oatf._buf, b.oatf._buf)


def test_compiled_tick_fills_angles_once_and_refuses_non_finite_errors() -> None:
    from controller import fast_tick

    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", oatf_mode="off")
    law = ControlLaw(law_config(cs), build_trajectory(cs))
    w = [12345, -4321, 7, -7]
    law.tick_compiled(0, *w)
    assert fast_tick.ANGLE_TABLE[0, w[0] + 32768] == measure_values(w)[8]
    assert fast_tick.ANGLE_TABLE[1, w[1] + 32768] == measure_values(w)[9]
    law._sp[1] = np.nan  # a set-point that is not a number: the PI refuses it as its Python form does
    before = law.pi.state.copy()
    with pytest.raises(ValueError, match="non-finite angle error"):
        law.tick_compiled(1, *w)
    assert np.array_equal(law.pi.state, before)


def test_pmin_pmax_keep_pythons_tie_rule() -> None:
    from controller.fast_tick import _pmax, _pmin

    for a, b in ((0.0, -0.0), (-0.0, 0.0), (1.0, 2.0), (2.0, 1.0), (-math.inf, 3.0)):
        assert _bits([_pmin(a, b), _pmax(a, b)]) == _bits([min(a, b), max(a, b)])


class _Wire:
    """A bus stand-in keeping what a link sends (a direct one, like the co-simulation's wire, offers ``send_frame``)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, bytes]] = []
        self.kinds: set[str] = set()

    def send(self, msg: Any, timeout: float | None = None) -> None:
        assert not (msg.is_extended_id or msg.is_remote_frame or msg.is_error_frame) and msg.dlc == len(msg.data)
        self.kinds.add(type(msg).__name__)
        self.frames.append((msg.arbitration_id, bytes(msg.data)))

    def recv(self, timeout: float | None = None) -> None:
        return None


class _DirectWire(_Wire):
    def send_frame(self, cob_id: int, data: bytes) -> None:
        self.kinds.add("send_frame")
        self.frames.append((cob_id, bytes(data)))


class _Forwarding:
    """A wrapper forwarding what it does not define (as the recording wire does): frames go through its send."""

    def __init__(self, inner: _Wire) -> None:
        self.inner = inner
        self.sent = 0

    def send(self, msg: Any, timeout: float | None = None) -> None:
        self.sent += 1
        self.inner.send(msg, timeout)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


def test_send_output_codes_is_send_output_values_of_the_codes_volts() -> None:
    """Every 12-bit D/A code: the RPDO1 the law's codes give (on a direct wire
    through its ``send_frame``, no frame object built) is the frame and the counters of send_output_values of
    the volts those codes stand for, which quantizes them back unclipped."""
    from controller.plant_link import PlantLink

    lsb = can_map.DAC12.lsb_v
    codes = list(range(can_map.DAC12.code_min, can_map.DAC12.code_max + 1))
    a, b = PlantLink(_DirectWire(), 1), PlantLink(_Wire(), 1)  # type: ignore[arg-type]
    for c0, c1 in zip(codes, reversed(codes), strict=True):
        a.send_output_codes(c0, c1)
        assert b.send_output_values([c0 * lsb, c1 * lsb]) == (False, False)
    assert a.bus.frames == b.bus.frames  # type: ignore[attr-defined]
    assert a.bus.kinds == {"send_frame"} and b.bus.kinds == {"Message"}  # type: ignore[attr-defined]
    assert a.counters == b.counters and a.counters.outputs_clipped == 0
    assert a.bus.frames[0] == (0x201, can_map.encode_analog_outputs([codes[0] << 4, codes[-1] << 4]))  # type: ignore[attr-defined]


def test_a_host_whose_compiled_sum_differs_keeps_the_python_form(monkeypatch: pytest.MonkeyPatch) -> None:
    """Where the compiled sum differs from the Python one (a compiler that fused a multiply-add) the law is not compiled and runs ``_compute``: the same rows."""
    from controller import fast_tick

    cs = ControllerSettings(duration_s=10.0, can_interface="virtual", oatf_mode="adaptive")
    compiled = ControlLaw(law_config(cs), build_trajectory(cs))
    monkeypatch.setattr(fast_tick, "_checked", False)
    plain = ControlLaw(law_config(cs), build_trajectory(cs))
    assert compiled.compiled and not plain.compiled
    for tick in range(200):
        w = [9000 + 16 * (tick % 7), 9000 - 16 * (tick % 5), 32 * (tick % 3), -48]
        assert _bits(compiled.step_row(tick, w)) == _bits(plain.step_row(tick, w))


def test_a_wrapper_that_forwards_send_frame_still_sees_every_frame() -> None:
    """The link takes the direct path only when the wire's class offers send_frame, so a
    forwarding wrapper around a direct wire (the co-simulation's recording) gets every frame."""
    from controller.plant_link import PlantLink

    wrapper = _Forwarding(_DirectWire())
    link = PlantLink(wrapper, 1)  # type: ignore[arg-type]
    link.send_output_codes(100, -100)
    link.send_sync()
    assert wrapper.sent == 2 and wrapper.inner.kinds == {"Message"}
