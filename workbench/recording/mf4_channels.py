"""Which numbers of a recording become which MDF channels: one table, pure.

A recorded message (JSON, :mod:`workbench.recording.schemas`) becomes one
sample of its topic's channel group; each numeric field a channel named
``<group>.<field>`` where ``<group>`` is the topic below ``/ralf/<rig>/``
with ``/`` as ``.`` (``plant.truth``, ``dsp.interrupt``, ``health.dsp``) or
``can.<DBC message>`` for the decoded CAN topics. :data:`FIELDS` names every
field of every message model with its channel, its unit (from the models'
field descriptions in ``protocol/messages.py`` and the schemas of
``workbench/recording/schemas.py``; the decoded CAN signals take theirs from
``protocol/ralf.dbc``) and, for a text state, the value-to-text conversion
MDF readers show. A tuple field is one channel per element (``_1``, ``_2``,
...); a field a message leaves out or sets to null is an *invalid* sample
(MDF invalidation bit), never a made-up value. The time of every sample is
the message's simulated time (``sim_time_s``).

Everything here is plain Python and numpy; :mod:`workbench.recording.mf4`
writes the result with asammdf.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
import numpy.typing as npt

from workbench.recording import schemas


@dataclass(frozen=True)
class Field:
    """One field of a message model: its JSON key, channel name, unit and text states."""

    key: str
    channel: str
    unit: str = ""
    states: tuple[str, ...] = ()
    """A text field stored as its index here (MDF value-to-text conversion)."""


def _f(key: str, unit: str = "", *, channel: str | None = None, states: tuple[str, ...] = ()) -> Field:
    return Field(key, channel or key, unit, states)


SEQ: Final = _f("seq")
SERVICE_STATES: Final = ("starting", "running", "degraded", "stopping", "failed")
FLAG_STATES: Final = ("empty", "full")

FIELDS: Final[dict[str, tuple[Field, ...]]] = {
    "ralf.GroundTruth": (
        SEQ,
        _f("modal_frequencies_hz", "Hz", channel="modal_frequency"),
        _f("damping_ratios", channel="damping_ratio"),
        _f("deflections_in", "in", channel="deflection"),
        _f("theta_rad", "rad", channel="theta"),
        _f("tip_in", "in", channel="tip"),
        _f("payload_attached"),
        _f("valves_held"),
    ),
    "ralf.ChannelTruth": (
        SEQ,
        _f("ai_true_v", "V", channel="ai_true"),
        _f("ai_faulted_v", "V", channel="ai_faulted"),
        _f("ai_saturated", channel="ai_saturated"),
        _f("ao_time_s", "s", channel="ao_time"),
        _f("ao_commanded_v", "V", channel="ao_commanded"),
        _f("ao_applied_v", "V", channel="ao_applied"),
    ),
    "ralf.Interrupt": (
        SEQ,
        _f("version"),
        _f("batch_seq"),
        _f("confidence"),
        _f("compute_time_s", "s", channel="compute_time"),
        _f("emulated_latency_s", "s", channel="emulated_latency"),
        _f("samples_in_history"),
        _f("valid_fraction"),
        _f("deadline_missed"),
    ),
    "ralf.ControllerStatus": (
        SEQ,
        _f("ticks"),
        _f("loop_rate_hz", "Hz", channel="loop_rate"),
        _f("batches_sent"),
        _f("interrupts"),
        _f("latest_frequency_hz", "Hz", channel="latest_frequency"),
        _f("deadline_misses"),
        _f("overruns"),
        _f("finished"),
    ),
    "ralf.BlockFlag": (
        SEQ,
        _f("state", states=FLAG_STATES),
        _f("next_batch_seq"),
        _f("fft_width"),
        _f("batch_size"),
        _f("emulated_latency_s", "s", channel="emulated_latency"),
        _f("config_seq"),
    ),
    "ralf.ConfigChange": (
        SEQ,
        _f("fft_width"),
        _f("batch_size"),
        _f("alpha"),
        _f("emulated_latency_s", "s", channel="emulated_latency"),
        _f("reset"),
    ),
    "ralf.ConfigAck": (
        SEQ,
        _f("accepted"),
        _f("fft_width"),
        _f("batch_size"),
        _f("alpha"),
        _f("emulated_latency_s", "s", channel="emulated_latency"),
    ),
    "ralf.Health": (SEQ, _f("state", states=SERVICE_STATES)),
    "ralf.SampleBatch": (SEQ, _f("first_tick"), _f("n_samples"), _f("dropped_before"), _f("sample_rate_hz", "Hz", channel="sample_rate")),
    "ralf.TfSnapshot": (SEQ, _f("batch_seq")),
    "ralf.ScenarioCommand": (
        SEQ,
        _f("kind", states=("payload", "seed", "adc_bits", "channel_fault")),
        _f("at_sim_time_s", "s", channel="at_sim_time"),
        _f("payload_attached"),
        _f("seed"),
        _f("adc_bits", "bit"),
    ),
    "ralf.ParamSet": (SEQ, _f("value")),
    "ralf.ParamAnswer": (SEQ, _f("accepted"), _f("value")),
    "ralf.ParamChanged": (SEQ, _f("tick"), _f("kind", states=("xcp", "param", "schedule"))),
}
"""Schema name -> its fields (the message's own numbers; ``sim_time_s`` is the time axis)."""

POLE_FIELDS: Final = (_f("frequency_hz", "Hz", channel="frequency"), _f("damping_ratio"), _f("magnitude"), _f("confidence"))
"""An interrupt's poles, first mode first: ``dsp.interrupt.pole_<k>.<field>``, plus ``dsp.interrupt.poles`` (how many)."""
LATENCY_FIELDS: Final = (_f("count"), _f("p50", "s"), _f("p99", "s"), _f("p999", "s"), _f("max", "s"))
"""A health message's latency percentiles: ``health.<service>.latency.<name>.<field>``; counters: ``health.<service>.counter.<name>``."""
BATCH_SAMPLES: Final = (_f("inputs", "V", channel="input"), _f("outputs", "in", channel="output"))
"""A batch's samples (the D/A commands and the measured tip deflections), one per control tick:
group ``dsp.batch.samples``, channels ``input_<valve>`` and ``output_<link>``."""
TF_ARRAYS: Final = (("freqs_hz", "Hz"), ("valid", ""))
"""A TF download's grid; each estimate adds ``<name>.magnitude`` and ``<name>.phase_rad`` (rad)."""
LEFT_OUT: Final[dict[str, str]] = {
    "ralf.Liveliness": "no simulated time (liveliness tokens)",
    "ralf.PlantEvent": "text (plant events)",
    "ralf.RawPayload": "undecodable payloads",
    "ralf.CanFrame": "",  # the CAN bus logging group
}
"""Schemas that give no channel, and why (empty: written another way)."""
DECODED_CAN_TIME_KEYS: Final = frozenset({"tick", "sim_time_s", "wall_time_s"})


@dataclass
class Column:
    """One channel: name, unit, values (one per sample, or one row per sample for an array), invalid samples."""

    name: str
    unit: str
    values: npt.NDArray[Any]
    invalid: npt.NDArray[np.bool_] | None = None
    states: tuple[str, ...] = ()


@dataclass
class Group:
    """One channel group: its name, the topic it comes from, the time of each sample and its channels."""

    name: str
    topic: str
    time_s: npt.NDArray[np.float64]
    columns: list[Column] = field(default_factory=list)
    note: str = ""


def group_name(topic: str) -> str:
    """``/ralf/<rig>/plant/truth`` -> ``plant.truth``; ``/can/decoded/SYNC`` -> ``can.SYNC``."""
    parts = topic.strip("/").split("/")
    if parts[:2] == ["can", "decoded"]:
        return ".".join(["can", *parts[2:]])
    if parts[0] == "ralf" and len(parts) > 2:
        parts = parts[2:]
    return ".".join(parts)


def column(name: str, unit: str, raw: Sequence[Any], states: tuple[str, ...] = ()) -> Column | None:
    """A channel from one value per sample (None: absent). Booleans become uint8, integers
    int64 (uint64 past its range), any float makes the channel float64 (integers exact below
    2**53); a text value its index in ``states``. None when no sample has a value."""
    invalid = np.array([v is None for v in raw], dtype=bool)
    present = [v for v in raw if v is not None]
    if not present:
        return None
    if states:
        unknown = sorted({str(v) for v in present if v not in states})
        if unknown:
            raise ValueError(f"{name}: value(s) {', '.join(unknown)} not among {', '.join(states)}")
        values: npt.NDArray[Any] = np.array([0 if v is None else states.index(v) for v in raw], dtype=np.uint8)
    elif all(isinstance(v, bool) for v in present):
        values = np.array([0 if v is None else int(v) for v in raw], dtype=np.uint8)
    elif all(isinstance(v, int) for v in present):
        big = max(present) >= 2**63
        values = np.array([0 if v is None else v for v in raw], dtype=np.uint64 if big else np.int64)
    elif all(isinstance(v, int | float) for v in present):
        values = np.array([0.0 if v is None else float(v) for v in raw], dtype=np.float64)
    else:
        raise ValueError(f"{name}: not a number: {next(v for v in present if not isinstance(v, int | float))!r}")
    return Column(name, unit, values, invalid if invalid.any() else None, states)


def _expanded(prefix: str, spec: Field, rows: Sequence[dict[str, Any]]) -> list[Column]:
    """A field's channel(s): one, or one per element of a tuple field."""
    values = [r.get(spec.key) for r in rows]
    out: list[Column | None]
    if any(isinstance(v, list) for v in values):
        width = max(len(v) for v in values if isinstance(v, list))
        out = [
            column(f"{prefix}.{spec.channel}_{i + 1}", spec.unit, [v[i] if isinstance(v, list) and i < len(v) else None for v in values]) for i in range(width)
        ]
    else:
        out = [column(f"{prefix}.{spec.channel}", spec.unit, values, spec.states)]
    return [c for c in out if c is not None]


def _keyed(rows: Sequence[dict[str, Any]], key: str) -> list[str]:
    """The names a dict field holds over all rows, in order of first appearance."""
    names: dict[str, None] = {}
    for r in rows:
        names.update(dict.fromkeys(r.get(key) or {}))
    return list(names)


def _health(prefix: str, rows: Sequence[dict[str, Any]]) -> list[Column]:
    cols: list[Column | None] = []
    for name in _keyed(rows, "counters"):
        cols.append(column(f"{prefix}.counter.{name}", "", [(r.get("counters") or {}).get(name) for r in rows]))
    for name in _keyed(rows, "latencies"):
        stats = [(r.get("latencies") or {}).get(name) or {} for r in rows]
        cols += [column(f"{prefix}.latency.{name}.{s.channel}", s.unit, [x.get(s.key) for x in stats]) for s in LATENCY_FIELDS]
    return [c for c in cols if c is not None]


def _poles(prefix: str, rows: Sequence[dict[str, Any]]) -> list[Column]:
    poles = [r.get("poles") or [] for r in rows]
    cols: list[Column | None] = [column(f"{prefix}.poles", "", [len(p) for p in poles])]
    for k in range(max((len(p) for p in poles), default=0)):
        for s in POLE_FIELDS:
            cols.append(column(f"{prefix}.pole_{k + 1}.{s.channel}", s.unit, [p[k].get(s.key) if k < len(p) else None for p in poles]))
    return [c for c in cols if c is not None]


def _param_unit(name: str) -> str:
    """A parameter's unit from its board's table (``workbench.params``; "" for a name no table holds)."""
    from protocol.errors import ConfigError
    from workbench.params import lookup

    try:
        return lookup(name)[1].unit
    except ConfigError:
        return ""


def _param_values(prefix: str, rows: Sequence[dict[str, Any]]) -> list[Column]:
    """A parameter change's names and values: ``<prefix>.name`` (the first parameter it sets, as
    text), ``<prefix>.value`` (that parameter's value) and ``<prefix>.value.<BOARD.NAME>`` per
    parameter, with its table's unit, invalid in the changes that leave it alone."""
    fields = [r.get("fields") or {} for r in rows]
    names = _keyed(rows, "fields")
    first = [next(iter(f), None) for f in fields]
    units = {n: _param_unit(n) for n in names}
    first_units = {units[n] for n in first if n is not None}
    cols: list[Column | None] = [
        column(f"{prefix}.name", "", first, tuple(names)),
        column(f"{prefix}.value", first_units.pop() if len(first_units) == 1 else "", [f[n] if n is not None else None for f, n in zip(fields, first)]),
    ]
    cols += [column(f"{prefix}.value.{n}", units[n], [f.get(n) for f in fields]) for n in names]
    return [c for c in cols if c is not None]


def dbc_units() -> dict[str, dict[str, str]]:
    """DBC message -> signal -> unit (``protocol/ralf.dbc``)."""
    return {m.name: {s.name: s.unit or "" for s in m.signals} for m in schemas.load_dbc().messages}


def left_out_because(schema: str) -> str:
    """Why a schema's messages give no channel group ("" when they give one)."""
    if schema in LEFT_OUT:
        return LEFT_OUT[schema] or "written another way"
    if schema in FIELDS or schema.startswith("ralf.dbc."):
        return ""
    return f"no MF4 channels defined for schema {schema or 'none'}"


def message_groups(topic: str, schema: str, rows: Sequence[dict[str, Any]], times: Sequence[float], units: dict[str, dict[str, str]]) -> list[Group]:
    """The channel group(s) of one topic's messages (empty for a schema :data:`LEFT_OUT`
    or one this table does not know: :func:`left_out_because` says why)."""
    if left_out_because(schema):
        return []
    prefix = group_name(topic)
    t = np.asarray(times, dtype=np.float64)
    if schema.startswith("ralf.dbc."):
        message = schema.removeprefix("ralf.dbc.")
        signals = [k for k in (rows[0] if rows else {}) if k not in DECODED_CAN_TIME_KEYS]
        cols = [column(f"{prefix}.{s}", units.get(message, {}).get(s, ""), [r.get(s) for r in rows]) for s in signals]
        return [Group(prefix, topic, t, [c for c in cols if c is not None], note=f"signals of DBC message {message}, decoded with protocol/ralf.dbc")]
    group = Group(prefix, topic, t, [c for spec in FIELDS[schema] for c in _expanded(prefix, spec, rows)])
    if schema == "ralf.Health":
        group.columns += _health(prefix, rows)
    elif schema == "ralf.Interrupt":
        group.columns += _poles(prefix, rows)
    elif schema == "ralf.ParamChanged":
        group.columns += _param_values(prefix, rows)
    elif schema == "ralf.SampleBatch":
        return [group, batch_samples(prefix, topic, rows)]
    elif schema == "ralf.TfSnapshot":
        return [group, *tf_groups(prefix, topic, rows, t)]
    return [group]


def batch_samples(prefix: str, topic: str, rows: Sequence[dict[str, Any]]) -> Group:
    """Every sample of every batch, at the batch's simulated time + i / sample rate."""
    times: list[npt.NDArray[np.float64]] = []
    for r in rows:
        n = int(r["n_samples"])
        times.append(float(r["sim_time_s"]) + np.arange(n, dtype=np.float64) / float(r["sample_rate_hz"]))
    group = Group(f"{prefix}.samples", topic, np.concatenate(times) if times else np.zeros(0), note="one sample per control tick")
    for spec in BATCH_SAMPLES:
        width = max((len(r[spec.key]) for r in rows), default=0)
        for i in range(width):
            values = np.concatenate([np.asarray(r[spec.key][i], dtype=np.float64) for r in rows])
            group.columns.append(Column(f"{prefix}.{spec.channel}_{i + 1}", spec.unit, values))
    return group


def tf_groups(prefix: str, topic: str, rows: Sequence[dict[str, Any]], times: npt.NDArray[np.float64]) -> list[Group]:
    """The TF downloads' arrays, one group per grid size (``<prefix>.bins_<n>``): one row of
    ``n`` values per download; an estimate a download lacks is an invalid sample."""
    by_size: dict[int, list[int]] = {}
    for i, r in enumerate(rows):
        by_size.setdefault(len(r["freqs_hz"]), []).append(i)
    groups: list[Group] = []
    for n, idx in by_size.items():
        g = Group(f"{prefix}.bins_{n}", topic, times[idx], note=f"transfer-function downloads of {n} bins: one row of {n} values per download")
        for key, unit in TF_ARRAYS:
            g.columns.append(Column(f"{g.name}.{key}", unit, np.array([rows[i][key] for i in idx], dtype=np.float64).reshape(len(idx), n)))
        names = _keyed([rows[i] for i in idx], "estimates")
        for name in names:
            for key, unit in (("magnitude", ""), ("phase_rad", "rad")):
                est = [rows[i]["estimates"].get(name) for i in idx]
                values = np.array([e[key] if e else [0.0] * n for e in est], dtype=np.float64).reshape(len(idx), n)
                invalid = np.array([e is None for e in est], dtype=bool)
                g.columns.append(Column(f"{g.name}.{name}.{key}", unit, values, invalid if invalid.any() else None))
        groups.append(g)
    return groups


def topic_rows(messages: Iterable[Any]) -> dict[str, tuple[str, list[dict[str, Any]], list[int]]]:
    """Topic -> (schema, the messages' data, their log times in ns), in recording order."""
    out: dict[str, tuple[str, list[dict[str, Any]], list[int]]] = {}
    for m in messages:
        entry = out.setdefault(m.topic, (m.schema, [], []))
        entry[1].append(m.data)
        entry[2].append(m.log_time_ns)
    return out


def sim_times(rows: Sequence[dict[str, Any]], log_ns: Sequence[int], t0_s: float) -> list[float]:
    """Each row's ``sim_time_s``; a row without one (a CAN frame before the first SYNC)
    at its log time's distance from ``t0_s``, the wall-clock time of simulated time 0."""
    out: list[float] = []
    for r, ns in zip(rows, log_ns):
        s = r.get("sim_time_s")
        out.append(float(s) if s is not None else ns / 1e9 - t0_s)
    return out
