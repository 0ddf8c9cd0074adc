"""Sweep specifications: a grid and/or a list of points over the three services' settings, seeds and the run mode.

A spec (YAML or TOML, see docs/campaigns.md) names settings as
``SERVICE.FIELD`` (``controller.oatf_mode``, ``plant.adc_bits``,
``dsp.fft_width``), ``common.FIELD`` or a bare ``FIELD`` (every service that
has it, like ``ralf-hil up --set``), one key of a structured setting as
``SERVICE.FIELD.KEY`` (``controller.oatf.frequency_hz``: the keys named
merge, the others keep their defaults), plus three special names, ``seed`` (the
plant's sensor-noise seed), ``mode`` (the run mode, :mod:`workbench.campaign.modes`)
and ``fault``: one channel fault (docs/fault-insertion.md) given as a table
(``fault: {channel: AI3, kind: short_ground, start_s: 5}``) or one field at a
time (``fault.kind``, ``fault.channel``, ``fault.offset_v``: the fields named
merge), checked as the plant checks it and added to the ``channel_faults`` of
the plant's ``scenario``, so a fault's kind, channel or size can be a grid axis.

The runs are ``points × grid × seeds``: every explicit point (default: one
empty point), crossed with the Cartesian product of the grid's axes, crossed
with the seeds, each merged over ``base`` (later wins: base < point < grid
value < seed); a point's optional ``label`` is its name in the table's
``point`` column. A grid axis whose values are tables is a *bundle*: each value
sets several settings at once (an optional ``label`` names it in the table).

Every run is resolved against the pydantic models of :mod:`protocol.settings`
(defaults filled in, values validated, the environment ignored) before
anything runs, so a typo fails the whole spec at once. The resolved settings,
minus the per-run plumbing (rig id, transport endpoints, record paths),
hash to the run's :attr:`RunPoint.key`; the rig id ``sw-<key>`` gives every
run its own ``ralf/<rig-id>`` namespace, and the results table is keyed by
it, so a resumed sweep skips the points it already finished.
"""

from __future__ import annotations

import functools
import hashlib
import itertools
import json
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from difflib import get_close_matches
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator
from pydantic_settings import BaseSettings

from protocol.bounded_parse import TooLarge, check_nesting, check_value, load_yaml
from protocol.files import NotARegularFile, read_regular_text
from protocol.setting_groups import SettingGroup, parse_group_text
from protocol.setting_hints import ANY, COMMON_SERVICE, unknown_setting
from protocol.settings import CommonSettings, ControllerSettings, DspSettings, PlantSettings, retired

__all__ = [
    "DEFAULT_MODE",
    "SERVICES",
    "VOLATILE",
    "RunPoint",
    "SpecError",
    "SweepSpec",
    "expand",
    "load_spec",
    "resolve",
]

SERVICES: dict[str, type[CommonSettings]] = {"controller": ControllerSettings, "plant": PlantSettings, "dsp": DspSettings}

VOLATILE = frozenset(
    {
        "rig_id",
        "zenoh_mode",
        "zenoh_connect",
        "zenoh_listen",
        "zenoh_multicast_scouting",
        "can_interface",
        "can_channel",
        "can_port",
        "run_record",
        "truth_record",
        "log_level",
    }
)
"""Per-run plumbing the run mode chooses: not part of a run's identity (its key)."""

SPECIAL = ("seed", "mode", "fault")

DEFAULT_MODE = "cosim"
"""The run mode of a spec that names none (:mod:`workbench.campaign.modes`): the one-thread
co-simulation, bit-identical to the three-process lockstep rig."""


class SpecError(ValueError):
    """The spec cannot be expanded: an unknown setting, a bad value, a bad layout."""


class SweepSpec(BaseModel):
    """A sweep (the file's top level)."""

    model_config = ConfigDict(extra="forbid")

    name: str = Field("sweep", description="Name of the campaign (the output directory's default name)")
    mode: str = Field(DEFAULT_MODE, description="Run mode of every run unless an axis or point says otherwise")
    seed: int = Field(0, ge=0, description="Base seed from which `seeds: N` derives N seeds")
    seeds: int | list[int] | None = Field(None, description="N derived seeds, or a list of plant seeds; every point runs once per seed")
    base: dict[str, Any] = Field(default_factory=dict, description="Settings of every run")
    grid: dict[str, list[Any]] = Field(default_factory=dict, description="Axes: setting -> values (a Cartesian product)")
    points: list[dict[str, Any]] = Field(
        default_factory=list, description="Explicit runs (each crossed with the grid); an optional `label` names one in the table"
    )

    @field_validator("base", "grid", mode="before")
    @classmethod
    def _flat(cls, value: Any) -> Any:
        return flatten(value) if isinstance(value, Mapping) else value

    @field_validator("points", mode="before")
    @classmethod
    def _flat_points(cls, value: Any) -> Any:
        return [flatten(p) if isinstance(p, Mapping) else p for p in value] if isinstance(value, list) else value

    @field_validator("grid")
    @classmethod
    def _non_empty_axes(cls, grid: dict[str, list[Any]]) -> dict[str, list[Any]]:
        for axis, values in grid.items():
            if not values:
                raise ValueError(f"grid axis {axis!r} has no values")
        return grid

    def seed_list(self) -> list[int | None]:
        """The plant seeds every point runs with (``[None]``: whatever the settings say)."""
        if self.seeds is None:
            return [None]
        if isinstance(self.seeds, int):
            if self.seeds < 1:
                raise SpecError("seeds must be at least 1")
            rng = np.random.default_rng([self.seed, 0x5EED])
            return [int(s) for s in rng.integers(0, 2**31 - 1, size=self.seeds)]
        return [int(s) for s in self.seeds]


@dataclass(frozen=True)
class RunPoint:
    """One resolved run."""

    index: int
    key: str
    """16 hex digits of the SHA-256 of the run's identity (mode and resolved settings, plumbing excluded)."""
    mode: str
    settings: dict[str, dict[str, Any]]
    """Resolved settings per service (every field, JSON-compatible values)."""
    axes: dict[str, Any] = field(default_factory=dict)
    """The values the spec varied for this run (axis name -> value or bundle label), for the table."""

    @property
    def rig_id(self) -> str:
        return f"sw-{self.key}"

    @property
    def seed(self) -> int:
        return int(self.settings["plant"]["seed"])

    def changed(self, service: str) -> dict[str, Any]:
        """The settings of ``service`` that differ from the model's defaults (for the three-process rig's ``RALF_*``)."""
        defaults = _defaults(service)
        return {k: v for k, v in self.settings[service].items() if k not in VOLATILE and k != "clock" and defaults.get(k) != v}


RunMode = Callable[[RunPoint], dict[str, Any]]
"""How a run is made: ``fn(point) -> metrics row``."""

_MODES: dict[str, RunMode] = {}
"""The run modes a spec may name; the built-in ones (:mod:`workbench.campaign.modes`)
register when the package is imported."""


def register_mode(name: str) -> Callable[[RunMode], RunMode]:
    """Register ``fn(point) -> metrics row`` as run mode ``name`` (decorator)."""

    def deco(fn: RunMode) -> RunMode:
        old = _MODES.get(name)
        if old is not None and (old.__module__, old.__qualname__) != (fn.__module__, fn.__qualname__):
            raise ValueError(f"run mode {name!r} is already registered by {old.__module__}")
        _MODES[name] = fn
        return fn

    return deco


def known_modes() -> list[str]:
    return sorted(_MODES)


def get_mode(name: str) -> RunMode:
    try:
        return _MODES[name]
    except KeyError:
        raise KeyError(f"unknown run mode {name!r}; known: {', '.join(known_modes())}") from None


# --------------------------------------------------------------------------- settings


def flatten(mapping: Mapping[str, Any]) -> dict[str, Any]:
    """Nested service tables to dotted names: ``{"plant": {"adc_bits": 16}}`` -> ``{"plant.adc_bits": 16}``
    (TOML's ``plant.adc_bits = 16`` and YAML's nested style both arrive nested); a structured
    setting's table to its keys: ``{"controller": {"oatf": {"damping": 0.01}}}`` -> ``controller.oatf.damping``."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if (key in SERVICES or key == "common") and isinstance(value, Mapping):
            for sub, v in value.items():
                if isinstance(v, Mapping):
                    out.update({f"{key}.{sub}.{k}": item for k, item in v.items()})
                else:
                    out[f"{key}.{sub}"] = v
        else:
            out[key] = value
    return out


@functools.cache
def _pure(model: type[CommonSettings]) -> type[CommonSettings]:
    """``model`` reading its init arguments only (no ``RALF_*`` environment, no dotenv)."""

    class Pure(model):  # type: ignore[misc, valid-type]
        @classmethod
        def settings_customise_sources(cls, settings_cls: type[BaseSettings], init_settings: Any, *sources: Any, **named: Any) -> tuple[Any, ...]:
            return (init_settings,)

    Pure.__name__ = model.__name__
    return Pure


@functools.cache
def _defaults_json(service: str) -> str:
    return json.dumps(_pure(SERVICES[service])().model_dump(mode="json"))


def _defaults(service: str) -> dict[str, Any]:
    return dict(json.loads(_defaults_json(service)))


def _split(name: str) -> list[tuple[str, str]]:
    """``SERVICE.FIELD`` / ``common.FIELD`` / ``FIELD`` -> the (service, field) pairs it sets."""
    if "." in name:
        service, _, fld = name.partition(".")
        if service == "common":
            if fld not in CommonSettings.model_fields:
                raise SpecError(f"{name!r}: {_unknown(fld, COMMON_SERVICE)}")
            return [(s, fld) for s in SERVICES]
        if service not in SERVICES:
            raise SpecError(f"{name!r}: unknown service {service!r} (controller, plant, dsp or common)")
        fields = SERVICES[service].model_fields
        group, dot, key = fld.partition(".")
        if dot:  # one key of a structured setting: controller.oatf.frequency_hz
            model = fields[group].annotation if group in fields else None
            if not (isinstance(model, type) and issubclass(model, SettingGroup)):
                raise SpecError(f"{name!r}: {service} has no structured setting {group!r}")
            if key not in model.model_fields:
                raise SpecError(f"{name!r}: {service}.{group} has no key {key!r}{_hint(key, model.model_fields)}")
            return [(service, fld)]
        if fld not in fields:
            raise SpecError(f"{name!r}: {_unknown(fld, service)}")
        return [(service, fld)]
    hits = [(s, name) for s, m in SERVICES.items() if name in m.model_fields]
    if not hits:
        raise SpecError(f"{name!r}: {_unknown(name, ANY)}")
    return hits


def _unknown(name: str, service: str) -> str:
    """Why ``name`` is not a setting of ``service``: the one line every program gives (a retired name: its reason)."""
    return unknown_setting(name, service) or retired(name) or f"{name!r} is not a setting of {service}"


def _hint(name: str, known: Any) -> str:
    close = get_close_matches(name, list(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def resolve(assignments: Mapping[str, Any]) -> tuple[str | None, dict[str, dict[str, Any]]]:
    """(mode or None, resolved settings per service) of a flat ``name -> value`` mapping; :class:`SpecError` if invalid."""
    mode: str | None = None
    given: dict[str, dict[str, Any]] = {s: {} for s in SERVICES}
    fault: dict[str, Any] = {}
    for name, value in assignments.items():
        if name == "mode":
            mode = str(value)
            continue
        if name == "seed":
            given["plant"]["seed"] = value
            continue
        if name == "fault":
            if not isinstance(value, Mapping):
                raise SpecError(f"fault: give a table of a channel fault's fields (channel, kind, start_s, ...), not {value!r}")
            fault.update(value)
            continue
        if name.startswith("fault."):
            fault[name.removeprefix("fault.")] = value
            continue
        for service, fld in _split(name):
            group, dot, key = fld.partition(".")
            if dot:
                entry = given[service].get(group) or {}
                given[service][group] = {**(parse_group_text(entry) if isinstance(entry, str) else dict(entry)), key: value}
            else:
                given[service][fld] = value
    if fault:
        given["plant"]["scenario"] = _with_fault(given["plant"].get("scenario"), fault)
    out: dict[str, dict[str, Any]] = {}
    for service, model in SERVICES.items():
        try:
            out[service] = _pure(model)(**given[service]).model_dump(mode="json")
        except ValidationError as exc:
            errs = "; ".join(f"{service}.{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in exc.errors())
            raise SpecError(f"invalid settings {dict(assignments)!r}: {errs}") from None
    return mode, out


def _with_fault(scenario: Any, fields: Mapping[str, Any]) -> str:
    """The plant's ``scenario`` with the sweep's channel fault added (checked: :class:`SpecError`, one line)."""
    from workbench.fiu import FaultError, build_fault, merge_scenario

    own = dict(fields)
    channel, kind = own.pop("channel", None), own.pop("kind", None)
    if channel is None or kind is None:
        raise SpecError(f"fault {dict(fields)!r}: needs channel and kind (docs/fault-insertion.md)")
    start, end = own.pop("start_s", 0.0), own.pop("end_s", None)
    try:
        if end is not None and not float(end) > float(start):
            raise FaultError(f"{kind} on {channel}: end_s {end} is not after start_s {start}")
        fault = build_fault(str(channel), str(kind), float(start), None if end is None else float(end) - float(start), **own)
    except (FaultError, TypeError, ValueError) as exc:
        raise SpecError(f"fault: {' '.join(str(exc).split())}") from None
    return json.dumps(merge_scenario(scenario, [fault]))


def identity(mode: str, settings: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """What makes a run the run it is: the mode and the settings without the plumbing."""
    return {"mode": mode, **{s: {k: v for k, v in sorted(settings[s].items()) if k not in VOLATILE} for s in SERVICES}}


def run_key(mode: str, settings: Mapping[str, Mapping[str, Any]]) -> str:
    text = json.dumps(identity(mode, settings), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()[:16]


# --------------------------------------------------------------------------- expansion


def _axis_values(axis: str, value: Any) -> tuple[dict[str, Any], Any]:
    """(assignments, value shown in the table) of one grid value."""
    if axis == "fault" and isinstance(value, Mapping):  # a channel fault's fields per value, merged over the base's
        shown = {k: v for k, v in value.items() if k != "label"}
        return {f"fault.{k}": v for k, v in shown.items()}, value.get("label", json.dumps(shown, sort_keys=True))
    if isinstance(value, Mapping):
        bundle = flatten(value)
        label = bundle.pop("label", None)
        if label is None:
            label = json.dumps(bundle, sort_keys=True)
        return bundle, label
    if axis in SPECIAL or "." in axis or any(axis in m.model_fields for m in SERVICES.values()):
        return {axis: value}, value
    raise SpecError(f"grid axis {axis!r} is not a setting; a bundle axis needs tables as values")


def planned_runs(spec: SweepSpec) -> int:
    """How many runs ``spec`` asks for, counted without resolving any (an upper
    bound: :func:`expand` keeps duplicate points once)."""
    return len(spec.points or [{}]) * math.prod(len(values) for values in spec.grid.values()) * len(spec.seed_list())


def expand(spec: SweepSpec) -> list[RunPoint]:
    """Every run of ``spec``, resolved and keyed (duplicates, by key, kept once)."""
    axes = list(spec.grid.items())
    combos = list(itertools.product(*[[(_axis_values(a, v)) for v in values] for a, values in axes])) if axes else [()]
    points = spec.points or [{}]
    seeds = spec.seed_list()
    runs: list[RunPoint] = []
    seen: set[str] = set()
    for p_index, point in enumerate(points):
        for combo in combos:
            for seed in seeds:
                own = dict(point)
                label = own.pop("label", None)
                assignments: dict[str, Any] = {**spec.base, **own}
                shown: dict[str, Any] = {}
                if len(points) > 1 or label is not None:
                    shown["point"] = p_index if label is None else label
                for (axis, _), (values, label) in zip(axes, combo):
                    assignments.update(values)
                    shown[axis] = label
                if seed is not None:
                    assignments["seed"] = seed
                    shown["seed"] = seed
                mode, settings = resolve(assignments)
                mode = mode or spec.mode
                if mode not in known_modes():
                    raise SpecError(f"unknown run mode {mode!r}; known: {', '.join(known_modes())}")
                if settings["controller"]["duration_s"] is None and settings["controller"]["repeats"] == 0:
                    raise SpecError(f"run {assignments!r} never ends: set controller.duration_s or controller.repeats")
                key = run_key(mode, settings)
                if key in seen:
                    continue
                seen.add(key)
                if "mode" in spec.grid or any("mode" in p for p in spec.points):
                    shown["mode"] = mode
                runs.append(RunPoint(len(runs), key, mode, settings, shown))
    return runs


def load_spec(path: str | Path) -> SweepSpec:
    """Read a spec from YAML (``.yaml``/``.yml``) or TOML (``.toml``)."""
    p = Path(path)
    try:
        text = read_regular_text(p)  # a FIFO or a device must not block the command
    except NotARegularFile as exc:
        raise SpecError(str(exc)) from None
    try:
        if p.suffix in (".yaml", ".yml"):
            data = load_yaml(text, str(p))
        elif p.suffix == ".toml":
            check_nesting(text, str(p))
            data = check_value(tomllib.loads(text), str(p))
        else:
            raise SpecError(f"{p}: a spec is .yaml, .yml or .toml")
    except TooLarge as exc:
        raise SpecError(str(exc)) from None
    except (SpecError, ModuleNotFoundError):
        raise  # a missing extra (yaml) is named by the command line, not as a parse error
    except Exception as exc:  # noqa: BLE001 - the parsers' own errors, with the file named
        raise SpecError(f"{p}: cannot parse: {exc}") from None
    if not isinstance(data, dict):
        raise SpecError(f"{p}: the top level must be a table")
    try:
        return SweepSpec.model_validate(data)
    except ValidationError as exc:
        raise SpecError(f"{p}: " + "; ".join(f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors())) from None
