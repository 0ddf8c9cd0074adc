"""The inputs a stimulus profile may drive: the single table of their names,
sides, units and physical ranges (:mod:`protocol.stimulus` validates against
it, docs/stimulus.md prints it).

Controller inputs act inside the control tick (:mod:`controller.loop`), plant
inputs inside the plant's application (:mod:`plant_emulator.service`).

One entry is a pattern, not a name: ``channel_fault.<n>.<size>`` names a size
(:data:`protocol.channel_faults.SIZES`) of fault ``n`` of the plant scenario's
``channel_faults`` section; :func:`lookup` resolves such a name to its
parameter's unit and schema range, the scenario's check
(:func:`protocol.stimulus.fault_size_ranges`) to the fault's own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Final, Literal

from protocol.can_map import FULL_SCALE_V
from protocol.channel_faults import SIZES, parameter_range

__all__ = [
    "CHANNEL_FAULT",
    "CONTROLLER_INPUTS",
    "INPUTS",
    "NAMES",
    "PLANT_INPUTS",
    "StimulusInput",
    "channel_fault_target",
    "describe_inputs",
    "lookup",
]

Side = Literal["controller", "plant"]


@dataclass(frozen=True)
class StimulusInput:
    """One input: where it acts, its unit and the range a profile must stay in."""

    name: str
    side: Side
    unit: str
    low: float
    high: float
    meaning: str
    pattern: re.Pattern[str] | None = None
    """A family of inputs (``name`` shows its form): the names it matches."""
    range_text: str | None = None
    """The table's range column where the range is not one (a pattern's)."""


_SIZE_RANGES = ", ".join(f"`{n}` {parameter_range(n)[0]:g} .. {parameter_range(n)[1]:g}{'' if u == '1' else ' ' + u}" for n, u in SIZES.items())
CHANNEL_FAULT: Final[StimulusInput] = StimulusInput(
    "channel_fault.<n>.<size>",
    "plant",
    ", ".join(dict.fromkeys(SIZES.values())),
    min(parameter_range(n)[0] for n in SIZES),
    max(parameter_range(n)[1] for n in SIZES),
    "replaces size `<size>` of fault `<n>` (its index) of the scenario's `channel_faults` while a profile on it is active, "
    "clipped to that range (a D/A output's stuck `value_v` to +-10 V); outside every window the fault's own value holds",
    pattern=re.compile(r"channel_fault\.(\d+)\.(\w+)"),
    range_text=_SIZE_RANGES,
)
"""The sizes of the plant scenario's channel faults (protocol/channel_faults.py)."""


_TABLE: Final[tuple[StimulusInput, ...]] = (
    StimulusInput(
        "setpoint.phi1",
        "controller",
        "rad",
        -0.2,
        0.2,
        "added to joint 1's set-point phi1 (the trajectory's) before the OATF and the PI",
    ),
    StimulusInput(
        "setpoint.phi2",
        "controller",
        "rad",
        -0.2,
        0.2,
        "added to joint 2's set-point phi2 (the trajectory's) before the OATF and the PI",
    ),
    StimulusInput(
        "valve.u1",
        "controller",
        "V",
        -FULL_SCALE_V,
        FULL_SCALE_V,
        "replaces valve 1's command (PI, inner OATF, dither) before the D/A while a profile on it is active",
    ),
    StimulusInput(
        "valve.u2",
        "controller",
        "V",
        -FULL_SCALE_V,
        FULL_SCALE_V,
        "replaces valve 2's command (PI, inner OATF, dither) before the D/A while a profile on it is active",
    ),
    StimulusInput(
        "payload",
        "plant",
        "1",
        0.0,
        1.0,
        "the 15.65 lb payload is attached while the value is >= 0.5 (released below), from the profile's start to its end",
    ),
    StimulusInput(
        "disturbance.link1",
        "plant",
        "N",
        -100.0,
        100.0,
        "force at link 1's tip (the elbow), perpendicular to link 1, positive towards increasing beta1",
    ),
    StimulusInput(
        "disturbance.link2",
        "plant",
        "N",
        -100.0,
        100.0,
        "force at link 2's tip (the arm's tip), perpendicular to link 2, positive towards increasing beta2",
    ),
    CHANNEL_FAULT,
)

INPUTS: Final[dict[str, StimulusInput]] = {i.name: i for i in _TABLE if i.pattern is None}
"""Every input with a fixed name, by name, in the table's order."""
NAMES: Final[tuple[str, ...]] = tuple(i.name for i in _TABLE)
"""The table's names and patterns, in its order (for messages)."""
CONTROLLER_INPUTS: Final[tuple[str, ...]] = tuple(i.name for i in _TABLE if i.side == "controller")
PLANT_INPUTS: Final[tuple[str, ...]] = tuple(i.name for i in _TABLE if i.side == "plant")


def channel_fault_target(name: str) -> tuple[int, str] | None:
    """``(fault index, size)`` of a ``channel_fault.<n>.<size>`` name (any word as the size), else None."""
    m = CHANNEL_FAULT.pattern.fullmatch(name) if CHANNEL_FAULT.pattern is not None else None
    return (int(m.group(1)), m.group(2)) if m else None


def lookup(name: str) -> StimulusInput | None:
    """The input ``name``: a fixed one, or a channel fault's size with its parameter's unit and
    schema range (the fault's own range is the scenario's check); None for no input."""
    fixed = INPUTS.get(name)
    if fixed is not None:
        return fixed
    target = channel_fault_target(name)
    if target is None or target[1] not in SIZES:
        return None
    low, high = parameter_range(target[1])
    return replace(CHANNEL_FAULT, name=name, unit=SIZES[target[1]], low=low, high=high, pattern=None, range_text=None)


def describe_inputs() -> str:
    """The table as Markdown (docs/stimulus.md)."""
    lines = ["| input | side | unit | range | what it does |", "| --- | --- | --- | --- | --- |"]
    for i in _TABLE:
        span = i.range_text if i.range_text is not None else f"{i.low:g} .. {i.high:g}"
        lines.append(f"| `{i.name}` | {i.side} | {i.unit} | {span} | {i.meaning} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(describe_inputs())
