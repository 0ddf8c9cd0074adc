"""The inputs a stimulus profile may drive: the single table of their names,
sides, units and physical ranges (:mod:`protocol.stimulus` validates against
it, docs/stimulus.md prints it).

Controller inputs act inside the control tick (:mod:`controller.loop`), plant
inputs inside the plant's application (:mod:`plant_emulator.service`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final, Literal

from protocol.can_map import FULL_SCALE_V

__all__ = ["CONTROLLER_INPUTS", "INPUTS", "PLANT_INPUTS", "StimulusInput", "describe_inputs"]

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
)

INPUTS: Final[dict[str, StimulusInput]] = {i.name: i for i in _TABLE}
"""Every input by name, in the table's order."""
CONTROLLER_INPUTS: Final[tuple[str, ...]] = tuple(i.name for i in _TABLE if i.side == "controller")
PLANT_INPUTS: Final[tuple[str, ...]] = tuple(i.name for i in _TABLE if i.side == "plant")


def describe_inputs() -> str:
    """The table as Markdown (docs/stimulus.md)."""
    lines = ["| input | side | unit | range | what it does |", "| --- | --- | --- | --- | --- |"]
    for i in _TABLE:
        lines.append(f"| `{i.name}` | {i.side} | {i.unit} | {i.low:g} .. {i.high:g} | {i.meaning} |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(describe_inputs())
