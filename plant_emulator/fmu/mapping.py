"""The mapping file that ties the plant node's I/O to an FMU's variables
(YAML, ``plant.fmu_mapping``; docs/fmu-plant.md).

The node's side is fixed by the protocol: RPDO1 carries two D/A channels
(valve 1, valve 2; volts after the 12-bit D/A), TPDO1 four A/D channels
(cylinder 1 extension, cylinder 2 extension, link 1 deflection, link 2
deflection). The mapping names, for each, the FMU variable on the other
side::

    inputs: [valve1_V, valve2_V]        # D/A channel 0, 1 -> FMU inputs (V)
    outputs:                            # FMU outputs -> A/D channels 0..3
      - {variable: x1, scale: 1.0, offset: -10.0}   # volts = scale * value + offset
      - {variable: x2, scale: 1.0, offset: -10.0}
      - {variable: w1, scale: 17.39}
      - {variable: w2, scale: 18.02}
    truth:                              # optional: ground truth on the test port
      modal_frequencies_hz: [f1, f2]
      damping_ratios: [z1, z2]
      deflections_in: [w1, w2]
    parameters: {payload_kg: 0.0}       # set before initialization
    start: {x1_start: 9.5}
    seed_variable: seed                 # optional: receives the plant's seed setting
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from protocol.bounded_parse import TooLarge, load_yaml
from protocol.errors import ConfigError
from protocol.files import NotARegularFile, read_regular_text

__all__ = ["FmuMapping", "OutputChannel", "TruthMapping", "load_mapping"]

Scalar = bool | int | float


class OutputChannel(BaseModel):
    """One A/D channel: ``volts = scale * value + offset``, then the A/D's bits."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    variable: str = Field(min_length=1, description="FMU output (Real / Float64)")
    scale: float = Field(1.0, description="Volts per unit of the variable")
    offset: float = Field(0.0, description="Volts added after scaling")

    @field_validator("scale", "offset")
    @classmethod
    def _finite(cls, v: float) -> float:
        if not math.isfinite(v):
            raise ValueError("must be a finite number")
        return v


class TruthMapping(BaseModel):
    """FMU variables published as ground truth on the test port (every one optional)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    modal_frequencies_hz: tuple[str, ...] = Field((), max_length=64)
    damping_ratios: tuple[str, ...] = Field((), max_length=64)
    deflections_in: tuple[str, str] | None = None
    theta_rad: tuple[str, str] | None = None
    tip_in: tuple[str, str] | None = None

    def variables(self) -> list[str]:
        """Every variable named, in the order :meth:`FmuPlant.truth_summary` reads them."""
        out = [*self.modal_frequencies_hz, *self.damping_ratios]
        for pair in (self.deflections_in, self.theta_rad, self.tip_in):
            out.extend(pair or ())
        return out


class FmuMapping(BaseModel):
    """The whole mapping file."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    inputs: tuple[str, str] = Field(description="FMU inputs fed with D/A channels 0 and 1 (valve volts after the D/A)")
    outputs: tuple[OutputChannel, OutputChannel, OutputChannel, OutputChannel] = Field(description="FMU outputs read into A/D channels 0..3 of TPDO1")
    truth: TruthMapping = TruthMapping()
    parameters: dict[str, Scalar] = Field(default_factory=dict, description="Parameter values set before initialization")
    start: dict[str, Scalar] = Field(default_factory=dict, description="Start values set before initialization")
    seed_variable: str | None = Field(None, description="Integer parameter that receives the plant's seed setting")


def load_mapping(path: str | Path) -> FmuMapping:
    """The mapping in ``path``; a bad file raises :class:`ConfigError` in one line naming it."""
    p = Path(path)
    try:
        text = read_regular_text(p)  # a FIFO or a device named here must not block the plant's start
    except NotARegularFile as exc:
        raise ConfigError(f"FMU mapping {exc}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"FMU mapping {p}: cannot be read ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        data = load_yaml(text, f"FMU mapping {p}")
    except TooLarge as exc:
        raise ConfigError(str(exc)) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"FMU mapping {p}: not YAML ({' '.join(str(exc).split())})") from None
    try:
        return FmuMapping.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(x) for x in first["loc"]) or "(top level)"
        raise ConfigError(f"FMU mapping {p}: {where}: {first['msg']}") from None
