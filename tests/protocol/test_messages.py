"""Control messages (protocol.messages): every model round-trips through
encode/decode, and every malformed payload raises ProtocolError naming what
was wrong -- never anything else."""

from __future__ import annotations

import inspect
import json
import math
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from protocol import messages as m
from protocol.errors import ProtocolError

FAST = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])

# --- strategies of valid instances -------------------------------------------------

finite = st.floats(min_value=-m.MAX_ABS, max_value=m.MAX_ABS, allow_nan=False, allow_infinity=False)
nonneg = st.floats(min_value=0.0, max_value=m.MAX_ABS, allow_nan=False, allow_infinity=False)
latency = st.floats(min_value=0.0, max_value=m.MAX_LATENCY_S, allow_nan=False)
hz = st.floats(min_value=0.0, max_value=1e5, allow_nan=False)
unit = st.floats(min_value=0.0, max_value=1.0, allow_nan=False)
seqs = st.integers(min_value=0, max_value=2**63 - 1)
counts = st.integers(min_value=0, max_value=2**63 - 1)
texts = st.text(max_size=20)
pow2_fft = st.integers(min_value=4, max_value=16).map(lambda k: 1 << k)


def _header() -> dict[str, Any]:
    return {"seq": seqs, "sim_time_s": nonneg, "wall_time_s": nonneg}


poles = st.builds(
    m.PoleParameters,
    frequency_hz=st.floats(min_value=0.0, max_value=1e5, exclude_min=True, allow_nan=False, allow_infinity=False),
    damping_ratio=st.floats(min_value=0.0, max_value=1e3, allow_nan=False),
    magnitude=nonneg,
    source=st.sampled_from(["tot", "11", "12", "21", "22"]),
)

latency_stats = st.builds(m.LatencyStats, count=counts, p50=nonneg, p99=nonneg, p999=nonneg, max=nonneg)


@st.composite
def scenario_commands(draw: st.DrawFn) -> m.ScenarioCommand:
    kind = draw(st.sampled_from(["payload", "seed", "adc_bits"]))
    values = {
        "payload_attached": draw(st.none() | st.booleans()),
        "seed": draw(st.none() | st.integers(min_value=0, max_value=2**32 - 1)),
        "adc_bits": draw(st.none() | st.sampled_from([12, 16, 20])),
    }
    needed = {"payload": "payload_attached", "seed": "seed", "adc_bits": "adc_bits"}[kind]
    if values[needed] is None:
        values[needed] = draw({"payload_attached": st.booleans(), "seed": st.integers(0, 2**32 - 1), "adc_bits": st.sampled_from([12, 16, 20])}[needed])
    return m.ScenarioCommand(**{k: draw(v) for k, v in _header().items()}, kind=kind, at_sim_time_s=draw(nonneg), **values)


request_ids = st.from_regex(r"[A-Za-z0-9_.:-]{1,64}", fullmatch=True)
param_names = st.from_regex(r"[A-Za-z0-9_]{1,20}\.[A-Za-z0-9_]{1,20}", fullmatch=True)
param_infos = st.builds(m.ParamInfo, name=param_names, unit=texts, lower=finite, upper=finite, value=st.none() | finite, description=texts)

STRATEGIES: dict[type[BaseModel], st.SearchStrategy[Any]] = {
    m.BlockFlag: st.builds(
        m.BlockFlag,
        **_header(),
        state=st.sampled_from(["empty", "full"]),
        next_batch_seq=seqs,
        fft_width=pow2_fft,
        batch_size=st.integers(1, 65536),
        emulated_latency_s=latency,
    ),
    m.PoleParameters: poles,
    m.Interrupt: st.builds(
        m.Interrupt,
        **_header(),
        batch_seq=seqs,
        poles=st.lists(poles, max_size=4).map(tuple),
        confidence=unit,
        compute_time_s=nonneg,
        emulated_latency_s=latency,
        samples_in_history=counts,
        valid_fraction=unit,
        deadline_missed=st.booleans(),
    ),
    m.ConfigChange: st.builds(
        m.ConfigChange,
        **_header(),
        fft_width=st.none() | st.integers(min_value=5, max_value=16).map(lambda k: 1 << k),
        batch_size=st.none() | st.integers(1, 4096),
        alpha=st.none() | st.floats(min_value=0.0, max_value=1.0, exclude_min=True, exclude_max=True),
        emulated_latency_s=st.none() | latency,
        request_id=st.none() | st.text("abcdef0123456789", min_size=1, max_size=32),
    ),
    m.ConfigAck: st.builds(
        m.ConfigAck,
        **_header(),
        request_id=st.none() | st.text("abcdef0123456789", min_size=1, max_size=32),
        accepted=st.booleans(),
        reason=texts,
        fft_width=pow2_fft,
        batch_size=st.integers(1, 65536),
        alpha=st.floats(min_value=0.0, max_value=1.0, exclude_min=True),
        emulated_latency_s=latency,
    ),
    m.LatencyStats: latency_stats,
    m.Health: st.builds(
        m.Health,
        **_header(),
        service=texts,
        state=st.sampled_from(["starting", "running", "degraded", "stopping", "failed"]),
        counters=st.dictionaries(texts, st.integers(-(2**63), 2**63 - 1), max_size=5),
        latencies=st.dictionaries(texts, latency_stats, max_size=3),
        last_miss=st.none() | texts,
    ),
    m.ControllerStatus: st.builds(
        m.ControllerStatus,
        **_header(),
        ticks=counts,
        loop_rate_hz=hz,
        batches_sent=counts,
        interrupts=counts,
        latest_frequency_hz=st.none() | hz,
        deadline_misses=counts,
        overruns=counts,
        finished=st.booleans(),
    ),
    m.GroundTruth: st.builds(
        m.GroundTruth,
        **_header(),
        modal_frequencies_hz=st.lists(finite, max_size=4).map(tuple),
        damping_ratios=st.lists(finite, max_size=4).map(tuple),
        deflections_in=st.tuples(finite, finite),
        theta_rad=st.tuples(finite, finite),
        tip_in=st.tuples(finite, finite),
        payload_attached=st.booleans(),
        valves_held=st.booleans(),
    ),
    m.ChannelTruth: st.builds(
        m.ChannelTruth,
        **_header(),
        ai_true_v=st.none() | st.tuples(finite, finite, finite, finite),
        ai_faulted_v=st.none() | st.tuples(finite, finite, finite, finite),
        ai_saturated=st.none() | st.tuples(st.booleans(), st.booleans(), st.booleans(), st.booleans()),
        ao_time_s=st.none() | st.floats(min_value=0.0, max_value=1e9),
        ao_commanded_v=st.none() | st.tuples(finite, finite),
        ao_applied_v=st.none() | st.tuples(finite, finite),
        active_faults=st.lists(texts, max_size=3).map(tuple),
    ),
    m.ScenarioCommand: scenario_commands(),
    m.PlantEvent: st.builds(m.PlantEvent, **_header(), kind=texts, detail=texts),
    m.ParamSet: st.builds(m.ParamSet, **_header(), request_id=request_ids, name=param_names, value=finite),
    m.ParamAnswer: st.builds(
        m.ParamAnswer, **_header(), request_id=request_ids, name=param_names, accepted=st.booleans(), reason=texts, value=st.none() | finite
    ),
    m.ParamInfo: param_infos,
    m.ParamTable: st.builds(
        m.ParamTable,
        **_header(),
        params=st.lists(param_infos, max_size=3).map(tuple),
        write_roles=st.lists(st.sampled_from(["tester", "tool"]), max_size=2).map(tuple),
    ),
    m.ParamChanged: st.builds(
        m.ParamChanged,
        **_header(),
        tick=counts,
        kind=st.sampled_from(["xcp", "param", "schedule"]),
        who=texts,
        fields=st.dictionaries(param_names, finite, max_size=4),
    ),
}

MODELS = sorted(STRATEGIES, key=lambda cls: cls.__name__)
MESSAGES = [cls for cls in MODELS if issubclass(cls, m.Message)]
any_model_instance = st.sampled_from(MODELS).flatmap(lambda cls: STRATEGIES[cls])


def test_every_model_in_the_module_has_a_strategy() -> None:
    defined = {obj for _, obj in inspect.getmembers(m, inspect.isclass) if issubclass(obj, BaseModel) and obj.__module__ == m.__name__ and obj is not m.Message}
    assert defined == set(STRATEGIES)


# --- round trips ---------------------------------------------------------------------


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
@FAST
@given(data=st.data())
def test_round_trip(model: type[BaseModel], data: st.DataObject) -> None:
    message = data.draw(STRATEGIES[model])
    payload = m.encode(message)
    assert isinstance(payload, bytes)
    back = m.decode(model, payload)
    assert back == message
    assert type(back) is model
    assert m.encode(back) == payload


@FAST
@given(message=any_model_instance)
def test_decode_accepts_bytearray_and_memoryview(message: BaseModel) -> None:
    payload = m.encode(message)
    assert m.decode(type(message), bytearray(payload)) == message
    assert m.decode(type(message), memoryview(payload)) == message


def test_round_trip_keeps_float_bits_of_extremes() -> None:
    # The largest values a field takes are its bounds (m.MAX_ABS); beyond them decoding refuses.
    values = (5e-324, -5e-324, 2.2250738585072014e-308, m.MAX_ABS, -m.MAX_ABS, -0.0, 0.1)
    truth = m.GroundTruth(
        seq=0,
        sim_time_s=5e-324,
        wall_time_s=m.MAX_ABS,
        modal_frequencies_hz=values,
        damping_ratios=values,
        deflections_in=(-0.0, 5e-324),
        theta_rad=(m.MAX_ABS, -m.MAX_ABS),
        tip_in=(0.1, 0.2),
        payload_attached=True,
    )
    back = m.decode(m.GroundTruth, m.encode(truth))
    assert [math.copysign(1.0, x) for x in back.modal_frequencies_hz] == [math.copysign(1.0, x) for x in values]
    assert np.array_equal(np.asarray(back.modal_frequencies_hz).view(np.uint64), np.asarray(values).view(np.uint64))
    assert back.sim_time_s == 5e-324 and back.wall_time_s == m.MAX_ABS
    with pytest.raises(ProtocolError, match="theta_rad"):
        m.decode(m.GroundTruth, m.encode(truth).replace(b"[1000000000000000.0,-1000000000000000.0]", b"[1.7976931348623157e308,-1e15]"))


def test_seq_extremes_round_trip() -> None:
    for seq in (0, 1, 2**53 + 1, 2**63 - 1):
        msg = m.PlantEvent(seq=seq, sim_time_s=0.0, kind="x")
        assert m.decode(m.PlantEvent, m.encode(msg)).seq == seq


def test_wall_time_defaults_to_now_and_models_are_frozen() -> None:
    before = time.time()
    msg = m.PlantEvent(seq=1, sim_time_s=0.5, kind="hard_stop")
    assert before <= msg.wall_time_s <= time.time()
    with pytest.raises(ValidationError):
        msg.seq = 2  # type: ignore[misc]


def test_protocol_error_is_a_value_error() -> None:
    assert issubclass(ProtocolError, ValueError)


# --- invalid payloads ----------------------------------------------------------------

VALID: dict[type[BaseModel], dict[str, Any]] = {
    m.BlockFlag: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "state": "empty", "next_batch_seq": 0, "fft_width": 2048, "batch_size": 20},
    m.PoleParameters: {"frequency_hz": 4.4, "damping_ratio": 0.09},
    m.Interrupt: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "batch_seq": 0, "confidence": 0.9, "compute_time_s": 0.01},
    m.ConfigChange: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "fft_width": 1024},
    m.ConfigAck: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "request_id": "ab12",
        "accepted": True,
        "fft_width": 1024,
        "batch_size": 30,
        "alpha": 0.1,
        "emulated_latency_s": 0.1,
    },
    m.LatencyStats: {"count": 3, "p50": 0.1, "p99": 0.2, "p999": 0.3, "max": 0.4},
    m.Health: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "service": "dsp", "counters": {"batches": 3}},
    m.ControllerStatus: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "ticks": 10, "loop_rate_hz": 200.0, "batches_sent": 1, "interrupts": 1},
    m.ChannelTruth: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "ai_true_v": [1.0, 2.0, 0.1, -0.2],
        "ai_faulted_v": [1.0, 2.0, 0.0, -0.2],
        "ai_saturated": [False, False, False, False],
        "active_faults": ["AI3 short_ground from 0.25 s"],
    },
    m.GroundTruth: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "modal_frequencies_hz": [4.4, 11.0],
        "damping_ratios": [0.09, 0.05],
        "deflections_in": [0.0, 0.0],
        "theta_rad": [0.1, 0.2],
        "tip_in": [30.0, 10.0],
        "payload_attached": False,
    },
    m.ScenarioCommand: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "kind": "seed", "seed": 7},
    m.PlantEvent: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "kind": "hard_stop"},
    m.ParamSet: {"seq": 1, "sim_time_s": 0.5, "wall_time_s": 1.0, "request_id": "ab12", "name": "controller.kp1", "value": 8000.0},
    m.ParamAnswer: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "request_id": "ab12",
        "name": "controller.kp1",
        "accepted": False,
        "reason": "outside its limits",
    },
    m.ParamInfo: {"name": "controller.kp1", "unit": "mV/rad", "lower": 0.0, "upper": 1e6, "value": 10000.0},
    m.ParamTable: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "params": [{"name": "controller.kp1", "unit": "mV/rad", "lower": 0.0, "upper": 1e6, "value": 10000.0}],
        "write_roles": ["tester"],
    },
    m.ParamChanged: {
        "seq": 1,
        "sim_time_s": 0.5,
        "wall_time_s": 1.0,
        "tick": 100,
        "kind": "schedule",
        "who": "schedule",
        "fields": {"controller.kp1": 8000.0},
    },
}


def _payload(doc: Any) -> bytes:
    return json.dumps(doc, allow_nan=True).encode()


def _with(model: type[BaseModel], **changes: Any) -> bytes:
    doc = json.loads(json.dumps(VALID[model]))
    doc.update(changes)
    return _payload(doc)


def _rejects(model: type[BaseModel], payload: bytes, *needles: str) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        m.decode(model, payload)
    text = str(info.value)
    assert model.__name__ in text
    for needle in needles:
        assert needle in text, f"{needle!r} not in {text!r}"
    return info.value


def test_valid_fixtures_decode() -> None:
    assert set(VALID) == set(STRATEGIES)
    for model, doc in VALID.items():
        assert isinstance(m.decode(model, _payload(doc)), model)


MALFORMED = [
    b"",
    b" ",
    b"{",
    b"}",
    b"{}}",
    b'{"seq": 1,}',
    b"[]",
    b"null",
    b"true",
    b"1",
    b'"text"',
    b"\xff\xfe\x00",
    b"\x00",
    b"{'seq': 1}",
    b"[" * 10_000,
    b'{"a":' * 10_000,
]


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
def test_malformed_json(model: type[BaseModel]) -> None:
    for payload in MALFORMED:
        _rejects(model, payload)


def test_truncated_payloads() -> None:
    for model, doc in VALID.items():
        payload = _payload(doc)
        for cut in range(len(payload)):
            with pytest.raises(ProtocolError):
                m.decode(model, payload[:cut])


WRONG_TYPES = [
    (m.Interrupt, "seq", "1"),
    (m.Interrupt, "seq", True),
    (m.Interrupt, "seq", 1.0),
    (m.Interrupt, "seq", 1.5),
    (m.Interrupt, "seq", [1]),
    (m.Interrupt, "seq", None),
    (m.Interrupt, "sim_time_s", "0.5"),
    (m.Interrupt, "sim_time_s", {}),
    (m.Interrupt, "confidence", True),
    (m.Interrupt, "confidence", "high"),
    (m.Interrupt, "deadline_missed", "yes"),
    (m.Interrupt, "deadline_missed", 1),
    (m.Interrupt, "poles", {"frequency_hz": 1.0}),
    (m.Interrupt, "poles", [{"frequency_hz": "4.4", "damping_ratio": 0.1}]),
    (m.BlockFlag, "state", "half"),
    (m.BlockFlag, "state", 1),
    (m.BlockFlag, "fft_width", "2048"),
    (m.BlockFlag, "batch_size", 20.0),
    (m.Health, "service", 5),
    (m.Health, "counters", {"a": "1"}),
    (m.Health, "counters", {"a": 1.5}),
    (m.Health, "counters", [1, 2]),
    (m.Health, "state", "zombie"),
    (m.Health, "latencies", {"x": {"count": 1}}),
    (m.GroundTruth, "payload_attached", "false"),
    (m.GroundTruth, "deflections_in", [0.0]),
    (m.GroundTruth, "deflections_in", [0.0, 0.0, 0.0]),
    (m.GroundTruth, "tip_in", "0,0"),
    (m.ScenarioCommand, "kind", "gravity"),
    (m.ScenarioCommand, "seed", "7"),
    (m.ScenarioCommand, "adc_bits", 14),
    (m.ControllerStatus, "ticks", -1),
    (m.ControllerStatus, "finished", None),
    (m.PlantEvent, "kind", None),
]


@pytest.mark.parametrize("model,field,value", WRONG_TYPES, ids=lambda x: getattr(x, "__name__", repr(x)))
def test_wrong_types_are_rejected_naming_the_field(model: type[BaseModel], field: str, value: Any) -> None:
    _rejects(model, _with(model, **{field: value}), field)


FLOAT_FIELDS = [
    (m.BlockFlag, "sim_time_s"),
    (m.BlockFlag, "wall_time_s"),
    (m.BlockFlag, "emulated_latency_s"),
    (m.PoleParameters, "frequency_hz"),
    (m.PoleParameters, "damping_ratio"),
    (m.PoleParameters, "magnitude"),
    (m.Interrupt, "confidence"),
    (m.Interrupt, "compute_time_s"),
    (m.Interrupt, "valid_fraction"),
    (m.Interrupt, "emulated_latency_s"),
    (m.ConfigChange, "alpha"),
    (m.ConfigChange, "emulated_latency_s"),
    (m.LatencyStats, "p50"),
    (m.LatencyStats, "max"),
    (m.ControllerStatus, "loop_rate_hz"),
    (m.ControllerStatus, "latest_frequency_hz"),
    (m.ScenarioCommand, "at_sim_time_s"),
    (m.PlantEvent, "sim_time_s"),
]


@pytest.mark.parametrize("model,field", FLOAT_FIELDS, ids=lambda x: getattr(x, "__name__", x))
def test_non_finite_numbers_are_rejected(model: type[BaseModel], field: str) -> None:
    for bad in ("NaN", "Infinity", "-Infinity", "1e400", "-1e400"):
        payload = _with(model, **{field: "__BAD__"}).replace(b'"__BAD__"', bad.encode())
        _rejects(model, payload, field)


@pytest.mark.parametrize(
    "model,path",
    [
        (m.GroundTruth, ("modal_frequencies_hz", 0)),
        (m.GroundTruth, ("damping_ratios", 1)),
        (m.GroundTruth, ("deflections_in", 0)),
        (m.GroundTruth, ("theta_rad", 1)),
        (m.GroundTruth, ("tip_in", 0)),
    ],
    ids=lambda x: getattr(x, "__name__", "-".join(map(str, x)) if isinstance(x, tuple) else x),
)
def test_non_finite_numbers_inside_sequences_are_rejected(model: type[BaseModel], path: tuple[Any, ...]) -> None:
    doc = json.loads(json.dumps(VALID[model]))
    target = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = "__BAD__"
    for bad in ("NaN", "Infinity", "-Infinity", "1e999"):
        _rejects(model, _payload(doc).replace(b'"__BAD__"', bad.encode()), ".".join(map(str, path)))


@pytest.mark.parametrize("field", ["seq", "sim_time_s", "wall_time_s"])
@pytest.mark.parametrize("model", MESSAGES, ids=lambda c: c.__name__)
def test_negative_header_values_are_rejected(model: type[BaseModel], field: str) -> None:
    _rejects(model, _with(model, **{field: -1}), field, "greater than or equal to 0")


@pytest.mark.parametrize("model", MESSAGES, ids=lambda c: c.__name__)
def test_seq_beyond_63_bits_is_rejected(model: type[BaseModel]) -> None:
    _rejects(model, _with(model, seq=2**63), "seq")
    _rejects(model, _with(model, seq=10**40), "seq")


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
def test_extra_fields_are_rejected(model: type[BaseModel]) -> None:
    _rejects(model, _with(model, bogus_field=1), "bogus_field", "Extra inputs are not permitted")


def test_extra_fields_in_nested_models_are_rejected() -> None:
    _rejects(m.Interrupt, _with(m.Interrupt, poles=[{"frequency_hz": 4.4, "damping_ratio": 0.1, "q": 1}]), "poles.0.q")


@pytest.mark.parametrize("model", MODELS, ids=lambda c: c.__name__)
def test_missing_required_fields_are_rejected_naming_them(model: type[BaseModel]) -> None:
    required = [name for name, field in model.model_fields.items() if field.is_required()]
    assert required
    for name in required:
        doc = dict(VALID[model])
        doc.pop(name)
        _rejects(model, _payload(doc), name, "Field required")


@pytest.mark.parametrize(
    "kind,field,value",
    [("payload", "payload_attached", True), ("seed", "seed", 3), ("adc_bits", "adc_bits", 16)],
)
def test_scenario_command_needs_its_value(kind: str, field: str, value: Any) -> None:
    base = {k: v for k, v in VALID[m.ScenarioCommand].items() if k != "seed"}
    _rejects(m.ScenarioCommand, _payload({**base, "kind": kind}), f"scenario command {kind!r} needs its value")
    _rejects(m.ScenarioCommand, _payload({**base, "kind": kind, field: None}), "needs its value")
    # another kind's value does not count
    others = {"payload_attached": True, "seed": 3, "adc_bits": 16}
    others.pop(field)
    _rejects(m.ScenarioCommand, _payload({**base, "kind": kind, **others}), "needs its value")
    assert getattr(m.decode(m.ScenarioCommand, _payload({**base, "kind": kind, field: value})), field) == value
    with pytest.raises(ValidationError):
        m.ScenarioCommand(seq=0, sim_time_s=0.0, kind=kind)


@FAST
@given(width=st.integers(min_value=33, max_value=65536).filter(lambda w: w & (w - 1)))  # ge=32: the identifier's minimum
def test_config_change_rejects_non_power_of_two_fft_width(width: int) -> None:
    _rejects(m.ConfigChange, _with(m.ConfigChange, fft_width=width), "power of two", str(width))
    with pytest.raises(ValidationError):
        m.ConfigChange(seq=0, sim_time_s=0.0, fft_width=width)


@FAST
@given(width=st.integers(min_value=16, max_value=65536).filter(lambda w: w & (w - 1)))
def test_block_flag_rejects_non_power_of_two_fft_width(width: int) -> None:
    _rejects(m.BlockFlag, _with(m.BlockFlag, fft_width=width), "power of two")


@pytest.mark.parametrize("width", [0, 8, 15, 131072, -16])
def test_fft_width_outside_limits(width: int) -> None:
    _rejects(m.ConfigChange, _with(m.ConfigChange, fft_width=width), "fft_width")
    _rejects(m.BlockFlag, _with(m.BlockFlag, fft_width=width), "fft_width")


@pytest.mark.parametrize(
    "field,value",
    [("alpha", 0.0), ("alpha", 1.0), ("batch_size", 0), ("batch_size", 4097), ("emulated_latency_s", -0.1)],
)
def test_config_change_limits(field: str, value: Any) -> None:
    _rejects(m.ConfigChange, _with(m.ConfigChange, **{field: value}), field)


def test_config_change_all_optional() -> None:
    change = m.decode(m.ConfigChange, _payload({"seq": 0, "sim_time_s": 0.0}))
    assert (change.fft_width, change.batch_size, change.alpha, change.emulated_latency_s) == (None, None, None, None)


@pytest.mark.parametrize(
    "model,field,value",
    [
        (m.PoleParameters, "frequency_hz", 0.0),
        (m.PoleParameters, "damping_ratio", -0.01),
        (m.Interrupt, "confidence", 1.0000001),
        (m.Interrupt, "valid_fraction", -0.1),
        (m.Interrupt, "samples_in_history", -1),
        (m.BlockFlag, "batch_size", 0),
        (m.LatencyStats, "count", -1),
        (m.ScenarioCommand, "seed", -1),
    ],
)
def test_range_limits(model: type[BaseModel], field: str, value: Any) -> None:
    _rejects(model, _with(model, **{field: value}), field)


# --- never anything but ProtocolError ------------------------------------------------


@settings(max_examples=200, deadline=None)
@given(model=st.sampled_from(MODELS), payload=st.binary(max_size=200))
def test_arbitrary_bytes_raise_only_protocol_error(model: type[BaseModel], payload: bytes) -> None:
    try:
        result = m.decode(model, payload)
    except ProtocolError:
        return
    assert isinstance(result, model)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda children: st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=8), children, max_size=4),
    max_leaves=20,
)


@settings(max_examples=100, deadline=None)
@given(model=st.sampled_from(MODELS), data=st.data())
def test_arbitrary_json_raises_only_protocol_error(model: type[BaseModel], data: st.DataObject) -> None:
    # start from a valid document and replace one field with an arbitrary JSON value
    doc = dict(VALID[model])
    field = data.draw(st.sampled_from([*model.model_fields, "unknown"]))
    doc[field] = data.draw(json_values)
    try:
        result = m.decode(model, _payload(doc))
    except ProtocolError:
        return
    assert isinstance(result, model)


@settings(max_examples=100, deadline=None)
@given(message=any_model_instance, data=st.data())
def test_corrupted_valid_payloads_raise_only_protocol_error(message: BaseModel, data: st.DataObject) -> None:
    payload = bytearray(m.encode(message))
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    try:
        result = m.decode(type(message), bytes(payload))
    except ProtocolError:
        return
    assert isinstance(result, type(message))


@settings(max_examples=100, deadline=None)
@given(message=any_model_instance, other=st.sampled_from(MODELS))
def test_decoding_as_the_wrong_model(message: BaseModel, other: type[BaseModel]) -> None:
    assume(other is not type(message))
    try:
        result = m.decode(other, m.encode(message))
    except ProtocolError:
        return
    assert isinstance(result, other)


def test_decode_error_keeps_the_validation_error_as_cause() -> None:
    err = _rejects(m.Interrupt, _with(m.Interrupt, confidence=2.0), "confidence")
    assert isinstance(err.__cause__, ValidationError)
    assert "1 error(s)" in str(err)
