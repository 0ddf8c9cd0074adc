"""Stimulus profiles from Python or YAML, as settings fragments for a rig.

::

    stim = Stimulus().step("valve.u1", 2.0, at_s=1.0, for_s=0.5).sine("disturbance.link2", amplitude=5.0, f_hz=4.0, at_s=2.0)
    fragments = stim.settings()            # {"controller": {"stimulus": [...]}, "plant": {"scenario": {"stimulus": [...]}}}
    rig = HilRig(controller={**fragments["controller"]}, plant_settings={**fragments["plant"]})

:meth:`Stimulus.settings` splits the profiles by the side their input lives on
(:mod:`protocol.stimulus_inputs`), validates each side as the services will
(:func:`protocol.stimulus.parse_stimulus`: a bad profile raises a one-line
:class:`~protocol.errors.ConfigError`) and merges the plant's profiles into
an existing ``scenario`` (its commands and channel faults kept, its stimulus
section extended). A YAML file is a list of profiles, or a mapping whose
``stimulus`` key holds one; file paths in playback profiles are taken
relative to the YAML file. docs/stimulus.md lists inputs and shapes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Literal

from protocol.errors import ConfigError
from protocol.stimulus import StimulusPlan, parse_stimulus
from protocol.stimulus_inputs import lookup

__all__ = ["Stimulus"]

_PATHS = ("csv", "npz", "mcap")


class Stimulus:
    """A list of stimulus profiles (each a mapping as :mod:`protocol.stimulus` reads it), built in order."""

    def __init__(self, profiles: list[dict[str, Any]] | None = None) -> None:
        self.profiles: list[dict[str, Any]] = [dict(p) for p in profiles or []]

    # -- shapes ---------------------------------------------------------------------------
    def add(self, input: str, shape: str, **fields: Any) -> Stimulus:
        """One profile of any shape; ``None`` fields are left out."""
        self.profiles.append({"input": input, "shape": shape, **{k: v for k, v in fields.items() if v is not None}})
        return self

    def step(self, input: str, size: float, *, at_s: float = 0.0, for_s: float | None = None, end_s: float | None = None) -> Stimulus:
        return self.add(input, "step", size=size, at_s=at_s, for_s=for_s, end_s=end_s)

    def ramp(
        self,
        input: str,
        *,
        slope: float | None = None,
        to: float | None = None,
        over_s: float | None = None,
        at_s: float = 0.0,
        for_s: float | None = None,
        end_s: float | None = None,
    ) -> Stimulus:
        return self.add(input, "ramp", slope=slope, to=to, over_s=over_s, at_s=at_s, for_s=for_s, end_s=end_s)

    def sine(
        self,
        input: str,
        amplitude: float,
        f_hz: float,
        *,
        phase_rad: float = 0.0,
        offset: float = 0.0,
        at_s: float = 0.0,
        for_s: float | None = None,
        end_s: float | None = None,
    ) -> Stimulus:
        return self.add(input, "sine", amplitude=amplitude, f_hz=f_hz, phase_rad=phase_rad, offset=offset, at_s=at_s, for_s=for_s, end_s=end_s)

    def chirp(
        self,
        input: str,
        amplitude: float,
        f0_hz: float,
        f1_hz: float,
        duration_s: float,
        *,
        method: Literal["linear", "logarithmic"] = "linear",
        phase_deg: float = 0.0,
        at_s: float = 0.0,
        for_s: float | None = None,
        end_s: float | None = None,
    ) -> Stimulus:
        return self.add(
            input,
            "chirp",
            amplitude=amplitude,
            f0_hz=f0_hz,
            f1_hz=f1_hz,
            duration_s=duration_s,
            method=method,
            phase_deg=phase_deg,
            at_s=at_s,
            for_s=for_s,
            end_s=end_s,
        )

    def prbs(
        self,
        input: str,
        amplitude: float,
        bit_s: float,
        *,
        seed: int = 1,
        register_bits: int = 10,
        at_s: float = 0.0,
        for_s: float | None = None,
        end_s: float | None = None,
    ) -> Stimulus:
        return self.add(input, "prbs", amplitude=amplitude, bit_s=bit_s, seed=seed, register_bits=register_bits, at_s=at_s, for_s=for_s, end_s=end_s)

    def playback(self, input: str, *, at_s: float = 0.0, for_s: float | None = None, end_s: float | None = None, **source: Any) -> Stimulus:
        """``csv=PATH`` (``column``, ``time_column``), ``npz=PATH, column=NAME``, ``mcap=PATH, topic=..., field=...``,
        or ``t=[...], values=[...]``; ``hold`` ``linear`` or ``zoh``, ``scale``, ``time_offset_s``."""
        for key in _PATHS:
            if source.get(key) is not None:
                source[key] = str(Path(source[key]))
        for key in ("t", "values"):
            if source.get(key) is not None:
                source[key] = [float(x) for x in source[key]]
        return self.add(input, "playback", at_s=at_s, for_s=for_s, end_s=end_s, **source)

    # -- files ----------------------------------------------------------------------------
    @classmethod
    def from_yaml(cls, path: str | Path) -> Stimulus:
        """The profiles of a YAML file (a list, or a mapping with ``stimulus``); relative playback paths from the file's folder."""
        import yaml

        p = Path(path)
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"cannot read {p}: {exc.strerror or exc}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"{p} is not YAML: {' '.join(str(exc).split())}") from None
        items = data.get("stimulus") if isinstance(data, dict) else data
        if not isinstance(items, list) or not all(isinstance(i, dict) for i in items):
            raise ConfigError(f"{p}: a stimulus file is a list of profiles, or a mapping with a 'stimulus' list")
        out = []
        for item in items:
            item = dict(item)
            for key in _PATHS:
                if isinstance(item.get(key), str) and not Path(item[key]).is_absolute():
                    item[key] = str(p.parent / item[key])
            out.append(item)
        return cls(out)

    # -- settings -------------------------------------------------------------------------
    def side(self, side: Literal["controller", "plant"]) -> list[dict[str, Any]]:
        """The profiles on that side's inputs, in order (an unknown input stays with the controller's, whose check names it)."""
        return [p for p in self.profiles if _side(p.get("input")) == side]

    def plans(self) -> tuple[StimulusPlan, StimulusPlan]:
        """Both sides validated as the services will: (controller's, plant's); one-line ConfigError otherwise."""
        return parse_stimulus(self.side("controller"), "controller"), parse_stimulus(self.side("plant"), "plant", where="scenario stimulus")

    def settings(self, scenario: str | list[Any] | dict[str, Any] | None = None) -> dict[str, dict[str, Any]]:
        """The settings fragments: ``controller.stimulus`` (when a controller input is driven) and
        ``plant.scenario`` (when a plant input is, or ``scenario`` is given), the plant's profiles
        appended to ``scenario``'s stimulus section (its other sections kept)."""
        self.plans()
        out: dict[str, dict[str, Any]] = {}
        controller, plant = self.side("controller"), self.side("plant")
        if controller:
            out["controller"] = {"stimulus": controller}
        if plant or scenario:
            merged = _scenario_object(scenario)
            if plant:
                merged["stimulus"] = [*merged.get("stimulus", []), *plant]
            out["plant"] = {"scenario": merged}
        return out

    def __len__(self) -> int:
        return len(self.profiles)


def _side(name: Any) -> str:
    spec = lookup(name) if isinstance(name, str) else None
    return spec.side if spec is not None else "controller"


def _scenario_object(scenario: str | list[Any] | dict[str, Any] | None) -> dict[str, Any]:
    """A plant ``scenario`` (JSON text, a list of commands, an object) as an object with sections."""
    value: Any = scenario
    if isinstance(scenario, str):
        if not scenario.strip():
            return {}
        try:
            value = json.loads(scenario)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"scenario is not JSON: {exc}") from None
    if value is None:
        return {}
    if isinstance(value, list):
        return {"commands": list(value)}
    if isinstance(value, dict):
        return {k: list(v) if isinstance(v, list) else v for k, v in value.items()}
    raise ConfigError("scenario must be a list of commands or an object with sections")
