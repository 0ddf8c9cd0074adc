"""A search space: which parts of a run may vary, and over what.

A space (YAML, JSON or Python, :class:`SearchSpace`) names the run's length,
the link faults, stalls and channel faults a scenario may hold (each a
template whose times, lengths and probabilities are ranges), and settings
that may take any value of a range or a list. Every range is a grid
``min, min + step, ..., max``: a drawn value is ``min + i * step``, so a
search that shrinks ``i`` toward 0 shrinks the value toward ``min``
(:mod:`workbench.search.strategies`). A bad space (an inverted range, an
empty list, an unknown link kind, channel or setting) is refused with one
line, before any run (:class:`SpaceError`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from protocol.channel_faults import AD_CHANNELS, DA_CHANNELS, ChannelFault
from protocol.files import read_regular_text
from service_kit.link_faults import KINDS

MAX_GRID = 1_000_000
"""The most values one range may hold (a step too fine for its span is refused)."""


class SpaceError(ValueError):
    """A search space that cannot be read or does not validate (one line)."""


class Range(BaseModel):
    """The values ``min, min + step, ..., max`` (``max`` rounded down to the grid).
    In a file: ``[min, max, step]``, ``{min: .., max: .., step: ..}`` or one number (a fixed value)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    min: float = Field(allow_inf_nan=False)
    max: float = Field(allow_inf_nan=False)
    step: float = Field(1.0, gt=0.0, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _shorthand(cls, data: Any) -> Any:
        if isinstance(data, bool):
            raise ValueError("a range is [min, max, step], {min, max, step} or a number")
        if isinstance(data, (int, float)):
            return {"min": data, "max": data}
        if isinstance(data, (list, tuple)):
            if len(data) not in (2, 3):
                raise ValueError(f"a range is [min, max] or [min, max, step], got {len(data)} values")
            return dict(zip(("min", "max", "step"), data, strict=False))
        return data

    @model_validator(mode="after")
    def _ordered(self) -> Range:
        if self.max < self.min:
            raise ValueError(f"inverted range: min {self.min:g} > max {self.max:g}")
        if self.count > MAX_GRID:
            raise ValueError(f"range [{self.min:g}, {self.max:g}] in steps of {self.step:g} holds over {MAX_GRID} values: take a coarser step")
        return self

    @property
    def count(self) -> int:
        """How many values the grid holds (at least 1)."""
        return int(math.floor((self.max - self.min) / self.step + 1e-9)) + 1

    def value(self, index: int) -> float:
        """The ``index``-th value of the grid (0: ``min``), rounded to 1e-9."""
        return round(self.min + index * self.step, 9)


class Choices(BaseModel):
    """One of a list of values (a search shrinks toward the first)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    choices: list[Any] = Field(min_length=1, max_length=1000)


def _range_or_none(data: Any) -> Any:
    return None if data is None else Range.model_validate(data)


class LinkFaultTemplate(BaseModel):
    """A link fault a scenario may hold: one of ``kinds`` on ``link``, active from
    ``start_s`` for ``length_s``, dropping with probability ``drop`` (1: every
    message, an outage), with an optional ``delay_s``, ``duplicate`` and ``reorder``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    link: str
    kinds: list[str] = Field(min_length=1, max_length=8)
    start_s: Range
    length_s: Range
    drop: Range = Range(min=1.0, max=1.0)
    delay_s: Range | None = None
    duplicate: Range | None = None
    reorder: Range | None = None

    @model_validator(mode="after")
    def _known(self) -> LinkFaultTemplate:
        if self.link not in KINDS:
            raise ValueError(f"unknown link {self.link!r} (can, zenoh)")
        unknown = [k for k in self.kinds if k not in KINDS[self.link]]
        if unknown:
            raise ValueError(f"{self.link} has no message kind {unknown[0]!r} (its kinds: {', '.join(KINDS[self.link])})")
        for name in ("drop", "duplicate", "reorder"):
            r: Range | None = getattr(self, name)
            if r is not None and (r.min < 0.0 or r.max > 1.0):
                raise ValueError(f"{name} is a probability: its range must lie in [0, 1]")
        if self.start_s.min < 0 or self.length_s.min < 0 or (self.delay_s is not None and self.delay_s.min < 0):
            raise ValueError("times and lengths must not be negative")
        return self


class StallTemplate(BaseModel):
    """A freeze of the controller's loop: at ``at_s`` (simulated), for ``wall_s`` of wall time."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    at_s: Range
    wall_s: Range

    @model_validator(mode="after")
    def _sane(self) -> StallTemplate:
        if self.at_s.min < 0 or self.wall_s.min < 0 or self.wall_s.max > 60:
            raise ValueError("a stall's at_s must not be negative and its wall_s must lie in [0, 60]")
        return self


def _ranged_params(params: dict[str, Any]) -> dict[str, Any]:
    """A template's parameters: a list of 2 or 3 numbers or a ``{min, max}`` mapping is a :class:`Range` (drawn), anything else fixed."""

    def ranged(v: Any) -> bool:
        numbers = isinstance(v, (list, tuple)) and len(v) in (2, 3) and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        return numbers or (isinstance(v, dict) and {"min", "max"} <= set(v))

    return {k: Range.model_validate(v) if ranged(v) else v for k, v in params.items()}


def param_value(r: Range, index: int) -> float | int:
    """A drawn parameter's value: an integer on an integer grid (a seed, a bit count), else the grid's float."""
    value = r.value(index)
    return int(value) if float(r.min).is_integer() and float(r.step).is_integer() else value


def params_at(params: dict[str, Any], end: int) -> dict[str, Any]:
    """The parameters with every range at its first (``end`` 0) or last (-1) value."""
    return {k: (param_value(v, 0 if end == 0 else v.count - 1) if isinstance(v, Range) else v) for k, v in params.items()}


class ChannelFaultTemplate(BaseModel):
    """A fault on one of the plant's signal channels (docs/fault-insertion.md):
    ``kind`` on one of ``channels``, from ``start_s`` for ``length_s``, with the
    kind's own fields in ``params``: each fixed, or drawn when it is a range
    (``offset_v: [-2, 0, 0.05]``: a search shrinks it toward ``min``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    channels: list[str] = Field(min_length=1, max_length=6)
    kind: str
    start_s: Range
    length_s: Range
    params: dict[str, Any] = Field(default_factory=dict)

    @field_validator("params", mode="after")
    @classmethod
    def _ranges(cls, params: dict[str, Any]) -> dict[str, Any]:
        return _ranged_params(params)

    @model_validator(mode="after")
    def _valid(self) -> ChannelFaultTemplate:
        for channel in self.channels:
            if channel not in AD_CHANNELS + DA_CHANNELS:
                raise ValueError(f"unknown channel {channel!r} ({', '.join(AD_CHANNELS + DA_CHANNELS)})")
            for end in (0, -1):
                try:  # the plant's own schema judges kind and params, per channel, at each end of the params' ranges
                    ChannelFault.model_validate({"channel": channel, "kind": self.kind, "start_s": 0.0, "end_s": 1.0, **params_at(self.params, end)})
                except ValidationError as exc:
                    raise ValueError(f"{channel} {self.kind}: " + "; ".join(e["msg"] for e in exc.errors())) from None
        return self


class StimulusTemplate(BaseModel):
    """A stimulus profile (docs/stimulus.md) a run may have: ``shape`` on one of ``inputs``,
    from ``start_s`` for ``length_s``; each of ``params`` is fixed, or drawn when it is a range
    (``size: [0, 40, 5]``: a search shrinks it toward ``min``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    inputs: list[str] = Field(min_length=1, max_length=16)
    shape: str
    start_s: Range
    length_s: Range
    params: dict[str, Any] = Field(default_factory=dict)

    @field_validator("params", mode="after")
    @classmethod
    def _ranges(cls, params: dict[str, Any]) -> dict[str, Any]:
        return _ranged_params(params)

    @model_validator(mode="after")
    def _valid(self) -> StimulusTemplate:
        from protocol.errors import ConfigError
        from workbench.stimulus import Stimulus

        if self.start_s.min < 0 or self.length_s.min < 0:
            raise ValueError("a stimulus's start_s and length_s must not be negative")
        for end in (0, -1):
            fields = {k: (v.value(0 if end == 0 else v.count - 1) if isinstance(v, Range) else v) for k, v in self.params.items()}
            for name in self.inputs:
                try:  # the services' own check of the profile, at each end of its ranges
                    Stimulus(
                        [{"input": name, "shape": self.shape, "at_s": self.start_s.value(0), "for_s": max(self.length_s.value(0), 1e-3), **fields}]
                    ).plans()
                except ConfigError as exc:
                    raise ValueError(f"{name} {self.shape}: {' '.join(str(exc).split())}") from None
        return self


Setting = Range | Choices
SERVICES = ("controller", "plant", "dsp", "common")


class SearchSpace(BaseModel):
    """What a search may vary (see the module's doc)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=1, max_length=64)] = "search"
    duration_s: Range
    """The run's length in simulated seconds (shrinks toward ``min``)."""
    link_faults: list[LinkFaultTemplate] = Field(default_factory=list, max_length=32)
    max_link_faults: Annotated[int, Field(ge=0, le=64)] = 2
    stalls: list[StallTemplate] = Field(default_factory=list, max_length=8)
    max_stalls: Annotated[int, Field(ge=0, le=64)] = 1
    channel_faults: list[ChannelFaultTemplate] = Field(default_factory=list, max_length=32)
    max_channel_faults: Annotated[int, Field(ge=0, le=64)] = 1
    stimuli: list[StimulusTemplate] = Field(default_factory=list, max_length=32)
    max_stimuli: Annotated[int, Field(ge=0, le=64)] = 1
    fault_seed: Range = Range(min=0, max=0)
    """The link-fault scenario's seed (its random drops, jitter, duplicates)."""
    settings: dict[str, Setting] = Field(default_factory=dict)
    """``SERVICE.NAME`` (or ``SERVICE.GROUP.KEY`` of a structured setting such as
    ``controller.timeouts.stale_after_s``) -> the values it may take."""
    fixed: dict[str, dict[str, Any]] = Field(default_factory=dict)
    """Settings every run has, per service (``controller: {batch_size: 20}``)."""

    @field_validator("settings", mode="before")
    @classmethod
    def _settings(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        return {k: (Choices.model_validate(v) if isinstance(v, dict) and "choices" in v else Range.model_validate(v)) for k, v in data.items()}

    @model_validator(mode="after")
    def _consistent(self) -> SearchSpace:
        if self.duration_s.min <= 0:
            raise ValueError("duration_s must be positive")
        if self.fault_seed.min < 0 or self.fault_seed.min != int(self.fault_seed.min) or self.fault_seed.step != int(self.fault_seed.step):
            raise ValueError("fault_seed is a range of non-negative integers")
        for key in self.settings:
            parts = key.split(".")
            if len(parts) not in (2, 3) or parts[0] not in SERVICES:
                raise ValueError(f"setting {key!r} is not SERVICE.NAME or SERVICE.GROUP.KEY ({', '.join(SERVICES)})")
        from workbench.hil import RigSettingError, check_settings

        unknown = set(self.fixed) - set(SERVICES)
        if unknown:
            raise ValueError(f"fixed: unknown service {sorted(unknown)[0]!r} ({', '.join(SERVICES)})")
        try:  # each name, the fixed values and every setting's ends (each choice), as the rig will judge them
            for end in (0, -1):
                check_settings({svc: {**self.fixed.get(svc, {}), **_end_values(self, svc, end)} for svc in SERVICES})
            for key, setting in self.settings.items():
                for choice in setting.choices if isinstance(setting, Choices) else ():
                    parts = key.split(".")
                    one: dict[str, Any] = {}
                    place_setting(one, parts[1:], choice, self.fixed.get(parts[0], {}))
                    check_settings({parts[0]: {**self.fixed.get(parts[0], {}), **one}})
        except RigSettingError as exc:
            raise ValueError(str(exc)) from None
        return self

    def digest(self) -> str:
        """A stable text of the space (for the example database's key)."""
        return json.dumps(self.model_dump(mode="json"), sort_keys=True)


def _end_values(space: SearchSpace, service: str, end: int) -> dict[str, Any]:
    """The space's varied settings of ``service`` at their first (``end`` 0) or last (-1) value."""
    out: dict[str, Any] = {}
    for key, setting in space.settings.items():
        parts = key.split(".")
        if parts[0] != service:
            continue
        value = setting.choices[end] if isinstance(setting, Choices) else setting.value(0 if end == 0 else setting.count - 1)
        if isinstance(setting, Range) and float(setting.min).is_integer() and float(setting.step).is_integer():
            value = int(value)  # as the strategies draw it
        place_setting(out, parts[1:], value, space.fixed.get(service, {}))
    return out


def place_setting(into: dict[str, Any], path: list[str], value: Any, fixed: dict[str, Any]) -> None:
    """Put ``value`` at ``NAME`` or ``GROUP.KEY`` of ``into`` (a group starts from its fixed keys)."""
    if len(path) == 1:
        into[path[0]] = value
        return
    group = into.setdefault(path[0], dict(fixed.get(path[0]) or {}))
    group[path[1]] = value


def load_space(path: str | Path) -> SearchSpace:
    """A space from a YAML or JSON file; :class:`SpaceError` (one line) when it is not one."""
    p = Path(path)
    try:
        text = read_regular_text(p)
    except OSError as exc:
        raise SpaceError(f"cannot read search space {p}: {exc.strerror or exc}") from None
    return parse_space(text)


def parse_space(text: str) -> SearchSpace:
    import yaml

    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SpaceError(f"search space is neither JSON nor YAML: {' '.join(str(exc).split())}") from None
    return space_from(data)


def space_from(data: Any) -> SearchSpace:
    """A space from a mapping (:class:`SpaceError` on a bad one)."""
    if isinstance(data, SearchSpace):
        return data
    if not isinstance(data, dict):
        raise SpaceError("a search space is a mapping (duration_s, link_faults, settings, ...)")
    try:
        return SearchSpace.model_validate(data)
    except ValidationError as exc:
        raise SpaceError(
            "invalid search space: " + "; ".join(f"{'.'.join(map(str, e['loc'])) or 'space'}: {e['msg'].removeprefix('Value error, ')}" for e in exc.errors())
        ) from None
