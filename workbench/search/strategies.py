"""Hypothesis strategies over the rig's own scenario formats.

:func:`candidates` draws a :class:`Candidate` from a :class:`SearchSpace`:
the run's length, a link-fault scenario (:mod:`service_kit.link_faults`:
``faults``, ``stalls``, ``seed``), the plant's channel faults
(:mod:`protocol.channel_faults`), stimulus profiles (:mod:`protocol.stimulus`)
and the varied settings. Every number is
drawn as an index into its range's grid and every list's length from 0, so
Hypothesis's shrinking (toward smaller integers, shorter lists, earlier
``one_of`` branches) moves a failing run toward fewer faults, a shorter
run, shorter and smaller faults that start and end earlier. Usable in a
user's own ``@given`` test (docs/fault-search.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from hypothesis import strategies as st

from workbench.search.space import (
    SERVICES,
    ChannelFaultTemplate,
    Choices,
    LinkFaultTemplate,
    Range,
    SearchSpace,
    StallTemplate,
    StimulusTemplate,
    param_value,
    place_setting,
)


@dataclass(frozen=True)
class Candidate:
    """One run a search tries: its length, its fault scenario, its settings."""

    duration_s: float
    scenario: dict[str, Any] = field(default_factory=dict)
    """A link-fault scenario (:class:`service_kit.link_faults.Scenario`'s fields ``seed``, ``faults``, ``stalls``)."""
    channel_faults: list[dict[str, Any]] = field(default_factory=list)
    """The plant's channel faults (:class:`protocol.channel_faults.ChannelFault`'s fields)."""
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Per service (controller, plant, dsp, common): the fixed and the drawn settings."""
    stimulus: list[dict[str, Any]] = field(default_factory=list)
    """Stimulus profiles (:mod:`protocol.stimulus`'s fields), either side's inputs."""

    def key(self) -> str:
        """The candidate as one stable text (equal runs, equal keys)."""
        return json.dumps(self.as_dict(), sort_keys=True)

    def as_dict(self) -> dict[str, Any]:
        return {
            "duration_s": self.duration_s,
            "scenario": self.scenario,
            "channel_faults": self.channel_faults,
            "settings": self.settings,
            "stimulus": self.stimulus,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Candidate:
        return cls(
            float(data["duration_s"]),
            dict(data.get("scenario") or {}),
            list(data.get("channel_faults") or []),
            dict(data.get("settings") or {}),
            list(data.get("stimulus") or []),
        )

    def faults(self) -> dict[str, Any] | None:
        """The rig's ``faults`` (None when the scenario holds no fault and no stall)."""
        if not self.scenario.get("faults") and not self.scenario.get("stalls"):
            return None
        return {"name": "search", **self.scenario}

    def rig_settings(self) -> dict[str, dict[str, Any]]:
        """Settings per service: the channel faults and the plant's stimulus in its ``scenario``
        setting, the controller's stimulus in its ``stimulus`` setting (:class:`workbench.stimulus.Stimulus`)."""
        from workbench.stimulus import Stimulus

        out = {svc: dict(self.settings.get(svc, {})) for svc in SERVICES}
        scenario = {"channel_faults": self.channel_faults} if self.channel_faults else None
        fragments = Stimulus(self.stimulus).settings(scenario=scenario) if self.stimulus or scenario else {}
        if "controller" in fragments:
            out["controller"]["stimulus"] = json.dumps(fragments["controller"]["stimulus"])
        if "plant" in fragments:
            out["plant"]["scenario"] = json.dumps(fragments["plant"]["scenario"])
        return out

    def describe(self) -> str:
        """One line: how big the candidate is."""
        faults = self.scenario.get("faults") or []
        parts = [f"{self.duration_s:g} s"]
        for f in faults:
            end = "" if f.get("stop_s") is None else f"-{f['stop_s']:g}"
            parts.append(f"{f['link']} {'/'.join(f['kinds'])} drop {f.get('drop', 0):g} at {f['start_s']:g}{end} s")
        parts += [f"stall {s['wall_s']:g} s at {s['at_s']:g} s" for s in self.scenario.get("stalls") or []]
        for c in self.channel_faults:
            extra = ", ".join(f"{k} {v:g}" for k, v in c.items() if k not in ("channel", "kind", "start_s", "end_s") and isinstance(v, (int, float)))
            parts.append(f"{c['channel']} {c['kind']}{' ' + extra if extra else ''} {c['start_s']:g}-{c['end_s']:g} s")
        for p in self.stimulus:
            extra = ", ".join(f"{k} {v:g}" for k, v in p.items() if k not in ("input", "shape", "at_s", "for_s") and isinstance(v, (int, float)))
            parts.append(f"{p['input']} {p['shape']}{' ' + extra if extra else ''} {p['at_s']:g}-{p['at_s'] + p['for_s']:g} s")
        varied = {f"{svc}.{k}": v for svc, values in self.settings.items() for k, v in values.items()}
        if varied:
            parts.append(", ".join(f"{k}={json.dumps(v)}" for k, v in varied.items()))
        return "; ".join(parts)


def values(r: Range) -> st.SearchStrategy[float]:
    """A value of ``r``'s grid, shrinking toward ``r.min``."""
    if r.count == 1:
        return st.just(r.value(0))
    return st.integers(min_value=0, max_value=r.count - 1).map(r.value)


def link_fault(t: LinkFaultTemplate) -> st.SearchStrategy[dict[str, Any]]:
    """One link fault (its window ``[start_s, start_s + length_s)``)."""

    def build(kind: str, start: float, length: float, drop: float, delay: float | None, duplicate: float | None, reorder: float | None) -> dict[str, Any]:
        out: dict[str, Any] = {"link": t.link, "kinds": [kind], "start_s": start, "stop_s": round(start + length, 9), "drop": drop}
        for name, value in (("delay_s", delay), ("duplicate", duplicate), ("reorder", reorder)):
            if value:
                out[name] = value
        return out

    def optional(r: Range | None) -> st.SearchStrategy[float | None]:
        return st.none() if r is None else values(r)

    return st.builds(
        build, st.sampled_from(t.kinds), values(t.start_s), values(t.length_s), values(t.drop), optional(t.delay_s), optional(t.duplicate), optional(t.reorder)
    )


def stall(t: StallTemplate) -> st.SearchStrategy[dict[str, Any]]:
    return st.fixed_dictionaries({"at_s": values(t.at_s), "wall_s": values(t.wall_s)})


def channel_fault(t: ChannelFaultTemplate) -> st.SearchStrategy[dict[str, Any]]:
    """One channel fault (its window ``[start_s, start_s + length_s)``), its ranged params drawn
    (an integer grid's as integers)."""

    def build(channel: str, start: float, length: float, params: dict[str, Any]) -> dict[str, Any]:
        return {"channel": channel, "kind": t.kind, "start_s": start, "end_s": round(start + length, 9), **params}

    def param(r: Range) -> st.SearchStrategy[float | int]:
        if r.count == 1:
            return st.just(param_value(r, 0))
        return st.integers(min_value=0, max_value=r.count - 1).map(lambda i: param_value(r, i))

    params = st.fixed_dictionaries({k: param(v) if isinstance(v, Range) else st.just(v) for k, v in t.params.items()})
    return st.builds(build, st.sampled_from(t.channels), values(t.start_s), values(t.length_s), params)


def stimulus_profile(t: StimulusTemplate) -> st.SearchStrategy[dict[str, Any]]:
    """One profile (its window ``[start_s, start_s + length_s)``, at least 1 ms), its ranged params drawn."""

    def build(name: str, start: float, length: float, params: dict[str, Any]) -> dict[str, Any]:
        return {"input": name, "shape": t.shape, "at_s": start, "for_s": max(length, 1e-3), **params}

    params = st.fixed_dictionaries({k: values(v) if isinstance(v, Range) else st.just(v) for k, v in t.params.items()})
    return st.builds(build, st.sampled_from(t.inputs), values(t.start_s), values(t.length_s), params)


def _some(templates: list[Any], make: Any, most: int) -> st.SearchStrategy[list[dict[str, Any]]]:
    if most == 0 or not templates:
        return st.just([])
    return st.lists(st.one_of(*[make(t) for t in templates]), max_size=most)


def setting_value(s: Range | Choices) -> st.SearchStrategy[Any]:
    if isinstance(s, Choices):
        return st.sampled_from(s.choices)
    v = values(s)
    return v.map(int) if all(float(x).is_integer() for x in (s.min, s.step)) else v


def candidates(space: SearchSpace) -> st.SearchStrategy[Candidate]:
    """Candidates of ``space``, shrinking toward fewer faults, shorter runs, smaller values."""

    def build(
        duration: float,
        faults: list[dict[str, Any]],
        stalls: list[dict[str, Any]],
        channel: list[dict[str, Any]],
        stimulus: list[dict[str, Any]],
        seed: float,
        drawn: dict[str, Any],
    ) -> Candidate:
        settings: dict[str, dict[str, Any]] = {svc: dict(v) for svc, v in space.fixed.items()}
        for key, value in drawn.items():
            parts = key.split(".")
            place_setting(settings.setdefault(parts[0], {}), parts[1:], value, space.fixed.get(parts[0], {}))
        scenario: dict[str, Any] = {"seed": int(seed), "faults": faults, "stalls": stalls} if faults or stalls else {}
        return Candidate(duration, scenario, channel, {k: v for k, v in settings.items() if v}, stimulus)

    return st.builds(
        build,
        values(space.duration_s),
        _some(space.link_faults, link_fault, space.max_link_faults),
        _some(space.stalls, stall, space.max_stalls),
        _some(space.channel_faults, channel_fault, space.max_channel_faults),
        _some(space.stimuli, stimulus_profile, space.max_stimuli),
        values(space.fault_seed),
        st.fixed_dictionaries({k: setting_value(v) for k, v in space.settings.items()}),
    )
