"""Stimulus profiles: the schema.

A profile drives one input (:mod:`protocol.stimulus_inputs`) with one shape
from ``at_s`` (simulated seconds, inclusive) until its end (exclusive:
``for_s`` after the start, or ``end_s``; without either, the shape's own end —
a chirp's ``duration_s``, a playback's last sample — or the run's end). Outside
that window a profile's value is 0. Shapes:

* ``step``: ``size``;
* ``ramp``: ``slope`` per second from 0, or from 0 to ``to`` over ``over_s``
  (then held);
* ``sine``: ``offset + amplitude sin(2 pi f_hz tau + phase_rad)``;
* ``chirp``: ``amplitude cos(phase(tau) + phase_deg)``, scipy.signal.chirp's
  ``linear`` or ``logarithmic`` sweep from ``f0_hz`` to ``f1_hz`` over ``duration_s``;
* ``prbs``: ``+-amplitude``, one bit of a maximal-length LFSR sequence of
  ``register_bits`` (period ``2**register_bits - 1``, scipy.signal.max_len_seq)
  every ``bit_s``, its register started from ``seed``;
* ``playback``: samples ``(t, value)`` (``t`` from the profile's start) from a
  CSV file (``csv``, columns ``t,value`` or named by ``time_column``/``column``),
  a controller record (``npz`` and ``column``, time ``t_s``), a recording
  (``mcap``, ``topic`` and ``field``, time ``sim_time_s``), or inline (``t`` and
  ``values``); ``hold`` ``linear`` (numpy.interp) or ``zoh`` (the last sample
  held); times before the first and after the last sample hold its value.

with ``tau = t - at_s``. Profiles on the same input add, in the order given;
the sum is clipped to the input's range (docs/stimulus.md).

The controller's ``stimulus`` setting holds the controller inputs' profiles
(a JSON list); the plant's ``scenario`` object a ``stimulus`` section with the
plant inputs'. Parsed and validated here (:func:`parse_stimulus`): an unknown
input, a profile that leaves its input's range, an end before its start, an
input of the other side are refused in one line.
"""

from __future__ import annotations

import csv
import functools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from protocol.bounded_parse import TooLarge, load_json
from protocol.channel_faults import SIZES, ChannelFault, size_range
from protocol.errors import ConfigError
from protocol.stimulus_inputs import CONTROLLER_INPUTS, INPUTS, NAMES, PLANT_INPUTS, Side, channel_fault_target, lookup

__all__ = [
    "Chirp",
    "Playback",
    "Prbs",
    "Profile",
    "Ramp",
    "Sine",
    "Step",
    "StimulusPlan",
    "fault_size_ranges",
    "parse_stimulus",
]

FloatArray = npt.NDArray[np.float64]
MAX_PLAYBACK_SAMPLES = 10_000_000


class _Shape(BaseModel):
    """What every profile has: its input and its window."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    input: str = Field(description="The input it drives (protocol/stimulus_inputs.py)")
    at_s: float = Field(0.0, ge=0.0, allow_inf_nan=False, description="Start, simulated seconds (inclusive)")
    for_s: float | None = Field(None, gt=0.0, allow_inf_nan=False, description="Length of the window (s)")
    end_s: float | None = Field(None, allow_inf_nan=False, description="End, simulated seconds (exclusive)")

    @model_validator(mode="after")
    def _window(self) -> Any:
        if lookup(self.input) is None:
            target = channel_fault_target(self.input)
            if target is not None:
                raise ValueError(f"{self.input}: no channel fault size {target[1]!r}; sizes: {', '.join(SIZES)}")
            raise ValueError(f"no stimulus input {self.input!r}; inputs: {', '.join(NAMES)}")
        if self.for_s is not None and self.end_s is not None:
            raise ValueError("give for_s or end_s, not both")
        if self.end_s is not None and self.end_s <= self.at_s:
            raise ValueError(f"end_s {self.end_s:g} is not after at_s {self.at_s:g}")
        return self

    @functools.cached_property
    def end(self) -> float | None:
        """The window's end (simulated s; None: the run's end)."""
        if self.end_s is not None:
            return self.end_s
        if self.for_s is not None:
            return self.at_s + self.for_s
        own = self._own_length()
        return None if own is None else self.at_s + own

    def _own_length(self) -> float | None:
        return None

    def bounds(self) -> tuple[float, float]:
        """The smallest and largest value the profile takes (0 outside its window included)."""
        lo, hi = self._shape_bounds()
        return min(lo, 0.0), max(hi, 0.0)

    def _shape_bounds(self) -> tuple[float, float]:
        raise NotImplementedError

    def describe(self) -> str:
        """One line for events and logs."""
        end = self.end
        fields = self.model_dump(exclude={"input", "at_s", "for_s", "end_s", "shape"}, exclude_none=True)
        params = " ".join(f"{k}={v}" for k, v in fields.items() if k not in ("t", "values"))
        until = "" if end is None else f" until {end:g} s"
        return f"{self.input} {getattr(self, 'shape', '?')} {params} from {self.at_s:g} s{until}".replace("  ", " ")


class Step(_Shape):
    shape: Literal["step"] = "step"
    size: float = Field(allow_inf_nan=False)

    def _shape_bounds(self) -> tuple[float, float]:
        return self.size, self.size


class Ramp(_Shape):
    shape: Literal["ramp"] = "ramp"
    slope: float | None = Field(None, allow_inf_nan=False, description="Per second, from 0 at the start")
    to: float | None = Field(None, allow_inf_nan=False, description="Reached after over_s, then held")
    over_s: float | None = Field(None, gt=0.0, allow_inf_nan=False)

    @model_validator(mode="after")
    def _one_form(self) -> Ramp:
        if (self.slope is None) == (self.to is None):
            raise ValueError("a ramp takes slope, or to and over_s")
        if self.to is not None and self.over_s is None:
            raise ValueError("a ramp to a value needs over_s")
        if self.slope is not None and self.over_s is not None:
            raise ValueError("over_s goes with to, not with slope")
        if self.slope is not None and self.slope != 0.0 and self.end is None:
            raise ValueError("a ramp by slope needs its end (for_s or end_s)")
        return self

    def _shape_bounds(self) -> tuple[float, float]:
        if self.to is not None:
            return self.to, self.to
        end = self.end
        top = float(self.slope or 0.0) * ((end - self.at_s) if end is not None else 0.0)
        return top, top


class Sine(_Shape):
    shape: Literal["sine"] = "sine"
    amplitude: float = Field(ge=0.0, allow_inf_nan=False)
    f_hz: float = Field(gt=0.0, allow_inf_nan=False)
    phase_rad: float = Field(0.0, allow_inf_nan=False)
    offset: float = Field(0.0, allow_inf_nan=False)

    def _shape_bounds(self) -> tuple[float, float]:
        return self.offset - self.amplitude, self.offset + self.amplitude


class Chirp(_Shape):
    shape: Literal["chirp"] = "chirp"
    amplitude: float = Field(ge=0.0, allow_inf_nan=False)
    f0_hz: float = Field(gt=0.0, allow_inf_nan=False)
    f1_hz: float = Field(gt=0.0, allow_inf_nan=False)
    duration_s: float = Field(gt=0.0, allow_inf_nan=False, description="Time to sweep from f0_hz to f1_hz; the window's end unless for_s/end_s")
    method: Literal["linear", "logarithmic"] = "linear"
    phase_deg: float = Field(0.0, allow_inf_nan=False, description="scipy.signal.chirp's phi (degrees; 0: a cosine)")

    def _own_length(self) -> float | None:
        return self.duration_s

    def _shape_bounds(self) -> tuple[float, float]:
        return -self.amplitude, self.amplitude


class Prbs(_Shape):
    shape: Literal["prbs"] = "prbs"
    amplitude: float = Field(ge=0.0, allow_inf_nan=False)
    bit_s: float = Field(gt=0.0, allow_inf_nan=False, description="How long each bit is held (s)")
    seed: int = Field(1, ge=0, lt=2**31, description="Start of the register (reduced to a non-zero state)")
    register_bits: int = Field(10, ge=2, le=24, description="The LFSR's length: period 2**register_bits - 1 bits")

    def _shape_bounds(self) -> tuple[float, float]:
        return -self.amplitude, self.amplitude


class Playback(_Shape):
    shape: Literal["playback"] = "playback"
    csv: str | None = Field(None, description="A CSV file with a header: time and value columns")
    npz: str | None = Field(None, description="A controller run record (.npz)")
    mcap: str | None = Field(None, description="A recording (ralf-hil up --record)")
    topic: str | None = Field(None, description="mcap: the topic, or its suffix after /ralf/RIG/ (e.g. plant/truth)")
    field: str | None = Field(None, description="mcap: the message field, dotted, list items by index (deflections_in.0)")
    column: str | None = Field(None, description="csv / npz: the value column (csv default: value)")
    time_column: str | None = Field(None, description="csv / npz: the time column (csv: t, npz: t_s; mcap: sim_time_s)")
    t: tuple[float, ...] | None = Field(None, description="Inline samples' times (s from the start)")
    values: tuple[float, ...] | None = None
    hold: Literal["linear", "zoh"] = "linear"
    scale: float = Field(1.0, allow_inf_nan=False, description="Each value times this")
    time_offset_s: float = Field(0.0, allow_inf_nan=False, description="Sample time t_src plays at at_s + t_src - time_offset_s")

    @model_validator(mode="after")
    def _one_source(self) -> Playback:
        sources = [n for n in ("csv", "npz", "mcap", "t") if getattr(self, n) is not None]
        if len(sources) != 1:
            raise ValueError("a playback takes one source: csv, npz (with column), mcap (with topic and field), or t and values")
        if self.npz is not None and self.column is None:
            raise ValueError("a playback from npz needs column")
        if self.mcap is not None and (self.topic is None or self.field is None):
            raise ValueError("a playback from mcap needs topic and field")
        if (self.t is None) != (self.values is None):
            raise ValueError("inline playback needs t and values")
        t, v = self.samples()
        if t.size == 0:
            raise ValueError(f"playback from {self._source()} has no samples")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v))):
            raise ValueError(f"playback from {self._source()} has non-finite samples")
        if np.any(np.diff(t) < 0.0):
            raise ValueError(f"playback from {self._source()}: times must not decrease")
        return self

    def _source(self) -> str:
        return str(self.csv or self.npz or self.mcap or "inline samples")

    def samples(self) -> tuple[FloatArray, FloatArray]:
        """``(t, value)``: times from the profile's start (s) and values (scaled), read once."""
        return self._samples

    @functools.cached_property
    def _samples(self) -> tuple[FloatArray, FloatArray]:
        t, v = _load_samples(self.csv, self.npz, self.mcap, self.topic, self.field, self.column, self.time_column, self.t, self.values)
        t, v = t - self.time_offset_s, v * self.scale
        t.setflags(write=False)
        v.setflags(write=False)
        return t, v

    def _own_length(self) -> float | None:
        t, _ = self.samples()
        last = float(t[-1])
        return last if last > 0.0 else None

    def _shape_bounds(self) -> tuple[float, float]:
        _, v = self.samples()
        return float(v.min()), float(v.max())


Profile = Annotated[Step | Ramp | Sine | Chirp | Prbs | Playback, Field(discriminator="shape")]
_PROFILES: TypeAdapter[list[Profile]] = TypeAdapter(list[Profile])


class StimulusPlan(BaseModel):
    """The profiles of one side, in the order given (their sum's order)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    profiles: tuple[Profile, ...] = ()

    def inputs(self) -> tuple[str, ...]:
        """The inputs driven, in the table's order."""
        used = {p.input for p in self.profiles}
        sizes = tuple(dict.fromkeys(p.input for p in self.profiles if p.input not in INPUTS))  # channel faults' sizes, in first use
        return (*(name for name in INPUTS if name in used), *sizes)

    def on(self, name: str) -> tuple[Profile, ...]:
        return tuple(p for p in self.profiles if p.input == name)

    def __bool__(self) -> bool:
        return bool(self.profiles)


def parse_stimulus(value: str | Sequence[Any], side: Side, where: str = "stimulus") -> StimulusPlan:
    """The profiles of ``value`` (JSON text or a list), validated for ``side``; one-line :class:`ConfigError` otherwise."""
    items: Any = value
    if isinstance(value, str):
        if not value.strip():
            return StimulusPlan()
        try:
            items = load_json(value, where)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{where} is not JSON: {exc}") from None
        except TooLarge as exc:
            raise ConfigError(str(exc)) from None
    if not isinstance(items, list | tuple):
        raise ConfigError(f"{where} must be a list of profiles")
    profiles = []
    for n, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"{where} item {n} must be an object")
        if "shape" not in item:
            raise ConfigError(f"{where} item {n}: shape missing; shapes: step, ramp, sine, chirp, prbs, playback")
        try:
            (profile,) = _PROFILES.validate_python([item])
        except ValidationError as exc:
            raise ConfigError(f"{where} item {n}: {_one_line(exc)}") from None
        spec = lookup(profile.input)
        assert spec is not None  # the profile's own check
        if spec.side != side:
            others = ", ".join(CONTROLLER_INPUTS if side == "controller" else PLANT_INPUTS)
            raise ConfigError(f"{where} item {n}: {profile.input} is a {spec.side} input; the {side}'s inputs: {others}")
        lo, hi = profile.bounds()
        if lo < spec.low or hi > spec.high:
            raise ConfigError(
                f"{where} item {n}: {profile.input} would reach {lo:g} .. {hi:g} {spec.unit}, outside its range {spec.low:g} .. {spec.high:g} {spec.unit}"
            )
        profiles.append(profile)
    return StimulusPlan(profiles=tuple(profiles))


def fault_size_ranges(plan: StimulusPlan, faults: Sequence[ChannelFault], where: str = "stimulus") -> dict[str, tuple[float, float]]:
    """The range of each channel fault's size the plan drives (``channel_fault.<n>.<size>``), the
    fault's own (:func:`protocol.channel_faults.size_range`); a profile on a fault ``faults`` does not
    have, on a size its kind does not take, or leaving that range is refused in one line."""
    ranges: dict[str, tuple[float, float]] = {}
    for n, profile in enumerate(plan.profiles):
        target = channel_fault_target(profile.input)
        if target is None:
            continue
        index, size = target
        if index >= len(faults):
            have = f"faults 0..{len(faults) - 1}" if faults else "no fault"
            raise ConfigError(f"{where} item {n}: {profile.input}: the scenario's channel_faults has {have}")
        fault = faults[index]
        try:
            lo, hi = size_range(fault, size)
        except ValueError as exc:
            raise ConfigError(f"{where} item {n}: {profile.input} ({fault.channel} {fault.kind}): {exc}") from None
        low, high = profile.bounds()
        if low < lo or high > hi:
            unit = SIZES[size]
            raise ConfigError(
                f"{where} item {n}: {profile.input} ({fault.channel} {fault.kind}) would reach {low:g} .. {high:g} {unit}, outside its range {lo:g} .. {hi:g} {unit}"
            )
        ranges[profile.input] = (lo, hi)
    return ranges


def _one_line(exc: ValidationError) -> str:
    parts = []
    for e in exc.errors():
        loc = [str(x) for x in e["loc"][1:] if not isinstance(x, int)]
        loc = [x for x in loc if x not in ("step", "ramp", "sine", "chirp", "prbs", "playback")]
        message = str(e["msg"]).removeprefix("Value error, ")
        parts.append(f"{'.'.join(loc)}: {message}" if loc else message)
    return "; ".join(dict.fromkeys(parts))


def _load_samples(
    csv_path: str | None,
    npz: str | None,
    mcap: str | None,
    topic: str | None,
    field: str | None,
    column: str | None,
    time_column: str | None,
    t: tuple[float, ...] | None,
    values: tuple[float, ...] | None,
) -> tuple[FloatArray, FloatArray]:
    """The samples of one playback source (read-only arrays)."""
    if t is not None and values is not None:
        if len(t) != len(values):
            raise ValueError(f"inline playback: {len(t)} times but {len(values)} values")
        ta, va = np.asarray(t, dtype=np.float64), np.asarray(values, dtype=np.float64)
    elif csv_path is not None:
        ta, va = _csv_samples(Path(csv_path), time_column or "t", column or "value")
    elif npz is not None:
        ta, va = _npz_samples(Path(npz), time_column or "t_s", str(column))
    else:
        ta, va = _mcap_samples(Path(str(mcap)), str(topic), str(field), time_column or "sim_time_s")
    ta.setflags(write=False)
    va.setflags(write=False)
    return ta, va


def _csv_samples(path: Path, t_name: str, v_name: str) -> tuple[FloatArray, FloatArray]:
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    if len(rows) > MAX_PLAYBACK_SAMPLES:
        raise ValueError(f"{path}: more than {MAX_PLAYBACK_SAMPLES} samples")
    if rows and (t_name not in rows[0] or v_name not in rows[0]):
        raise ValueError(f"{path} has no columns {t_name!r} and {v_name!r}; it has {', '.join(map(str, rows[0]))}")
    try:
        return np.array([float(r[t_name]) for r in rows]), np.array([float(r[v_name]) for r in rows])
    except (TypeError, ValueError):
        raise ValueError(f"{path}: a row of {t_name!r}, {v_name!r} is not a number") from None


def _npz_samples(path: Path, t_name: str, v_name: str) -> tuple[FloatArray, FloatArray]:
    try:
        with np.load(path, allow_pickle=False) as data:
            missing = [n for n in (t_name, v_name) if n not in data.files]
            if missing:
                raise ValueError(f"{path} has no column {missing[0]!r}; it has {', '.join(data.files)}")
            ta, va = np.asarray(data[t_name], dtype=np.float64), np.asarray(data[v_name], dtype=np.float64)
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    if ta.ndim != 1 or va.shape != ta.shape:
        raise ValueError(f"{path}: {v_name!r} is not one value per {t_name!r}")
    return ta, va


def _mcap_samples(path: Path, topic: str, field: str, t_name: str) -> tuple[FloatArray, FloatArray]:
    try:
        from mcap.reader import make_reader
    except ImportError:
        raise ValueError("playback from a recording needs the mcap package (pip install 'ralf-hil[rig]')") from None
    times: list[float] = []
    vals: list[float] = []
    try:
        with open(path, "rb") as fh:
            for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
                name = channel.topic
                if name != topic and not name.endswith("/" + topic.strip("/")):
                    continue
                data = json.loads(message.data)
                times.append(float(data[t_name]) if t_name in data else message.log_time / 1e9)
                vals.append(_field(data, field, path))
                if len(times) > MAX_PLAYBACK_SAMPLES:
                    raise ValueError(f"{path}: more than {MAX_PLAYBACK_SAMPLES} samples on {topic}")
    except OSError as exc:
        raise ValueError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not times:
        raise ValueError(f"{path} has no message on topic {topic!r}")
    return np.array(times), np.array(vals)


def _field(data: Any, dotted: str, path: Path) -> float:
    value = data
    for part in dotted.split("."):
        try:
            value = value[int(part)] if isinstance(value, list) else value[part]
        except (KeyError, IndexError, ValueError, TypeError):
            raise ValueError(f"{path}: a message has no field {dotted!r}") from None
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{path}: field {dotted!r} is not a number") from None
    if not math.isfinite(out):
        raise ValueError(f"{path}: field {dotted!r} is not finite")
    return out
