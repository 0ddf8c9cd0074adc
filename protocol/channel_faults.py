"""Faults on the plant node's signal channels: the schedule's schema.

The plant's ``scenario`` setting may be a JSON object with a
``channel_faults`` section beside its ``commands``: a list of
:class:`ChannelFault`, each a fault on one A/D input (``AI1`` .. ``AI4``,
TPDO1 order) or one D/A output (``AO1``, ``AO2``, RPDO1 order) from
``start_s`` to ``end_s`` of simulated time. Validated here, where the
settings load (a bad schedule is refused in one line before the plant's node
boots); applied by :mod:`plant_emulator.channel_faults`. docs/fault-insertion.md
describes every kind.
"""

from __future__ import annotations

import math
from typing import Final, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator

from protocol.can_map import ADC_RESOLUTIONS, FULL_SCALE_V

__all__ = [
    "AD_CHANNELS",
    "AD_KINDS",
    "DA_CHANNELS",
    "DA_KINDS",
    "DEFAULT_OPEN_V",
    "DEFAULT_SUPPLY_V",
    "ChannelFault",
    "SIZES",
    "FaultSchedule",
    "size_range",
]

AD_CHANNELS: Final[tuple[str, ...]] = ("AI1", "AI2", "AI3", "AI4")
"""The A/D inputs, TPDO1 order (0x6401 sub 1-4)."""
DA_CHANNELS: Final[tuple[str, ...]] = ("AO1", "AO2")
"""The D/A outputs, RPDO1 order (0x6411 sub 1-2): the two valves."""
AdKind = Literal[
    "open",
    "short_ground",
    "short_supply",
    "stuck",
    "offset",
    "gain",
    "noise",
    "drift",
    "intermittent",
    "lost_bits",
    "delay",
    "short_channels",
]
"""The fault kinds of an A/D input."""
AD_KINDS: Final[tuple[str, ...]] = get_args(AdKind)
DaKind = Literal["open", "stuck", "offset", "gain", "saturate", "delay"]
"""The fault kinds of a D/A output."""
DA_KINDS: Final[tuple[str, ...]] = get_args(DaKind)

DEFAULT_OPEN_V: Final[float] = 0.0
"""What an open A/D input reads unless ``value_v`` says otherwise: the
AVME 9325's inputs are differential with bias-return resistors, so an open
pair settles at 0 V (a board with pull-ups would read a rail: set ``value_v``)."""
DEFAULT_SUPPLY_V: Final[float] = 15.0
"""The sensors' supply rail a ``short_supply`` connects an input to (beyond
the converter's +10 V full scale: the code clips and is flagged saturated)."""
INPUT_RANGE_V: Final[float] = 15.0
"""An A/D input's physical range: the sensors' supply rails, +-15 V."""
MAX_DELAY_SAMPLES: Final[int] = 10_000
MAX_LOST_BITS: Final[int] = max(ADC_RESOLUTIONS) - 1

Channel = Literal["AI1", "AI2", "AI3", "AI4", "AO1", "AO2"]
Kind = Literal[AdKind, DaKind]
"""Every fault kind (an A/D input's, then the D/A outputs' own)."""

_NEEDS: Final[dict[str, tuple[str, ...]]] = {
    "offset": ("offset_v",),
    "gain": ("factor",),
    "noise": ("sigma_v", "seed"),
    "drift": ("rate_v_s",),
    "intermittent": ("period_s", "duty"),
    "lost_bits": ("bits",),
    "delay": ("samples",),
    "short_channels": ("other",),
    "saturate": ("limit_v",),
}
"""The parameters each kind needs (the others are optional or unused)."""
_TAKES: Final[dict[str, frozenset[str]]] = {
    "open": frozenset({"value_v"}),
    "short_supply": frozenset({"value_v"}),
    "stuck": frozenset({"value_v"}),
    "intermittent": frozenset({"period_s", "duty", "value_v"}),
}
"""The parameters each kind accepts, where more than those it needs."""
_PARAMETERS: Final[tuple[str, ...]] = (
    "value_v",
    "offset_v",
    "factor",
    "sigma_v",
    "seed",
    "rate_v_s",
    "period_s",
    "duty",
    "bits",
    "samples",
    "other",
    "limit_v",
)


SIZES: Final[dict[str, str]] = {
    "offset_v": "V",
    "factor": "1",
    "sigma_v": "V",
    "rate_v_s": "V/s",
    "value_v": "V",
}
"""The sizes a stimulus profile may drive (docs/stimulus.md), with their units: the float
parameters whose range holds 0 (a profile is 0 outside its window)."""


class ChannelFault(BaseModel):
    """One fault on one channel, active from ``start_s`` (inclusive) until
    ``end_s`` (exclusive; None: to the end of the run), simulated seconds."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    channel: Channel = Field(description="AI1..AI4 (A/D inputs, TPDO1 order) or AO1, AO2 (D/A outputs, the valves)")
    kind: Kind
    start_s: float = Field(0.0, ge=0.0, allow_inf_nan=False)
    end_s: float | None = Field(None, allow_inf_nan=False)
    value_v: float | None = Field(None, ge=-INPUT_RANGE_V, le=INPUT_RANGE_V, allow_inf_nan=False)
    """open / intermittent: what the open input reads; stuck: the value held (None: the value at the start); short_supply: the rail."""
    offset_v: float | None = Field(None, ge=-2 * FULL_SCALE_V, le=2 * FULL_SCALE_V, allow_inf_nan=False)
    factor: float | None = Field(None, ge=-10.0, le=10.0, allow_inf_nan=False)
    sigma_v: float | None = Field(None, ge=0.0, le=FULL_SCALE_V, allow_inf_nan=False)
    seed: int | None = Field(None, ge=0, lt=2**32)
    rate_v_s: float | None = Field(None, ge=-FULL_SCALE_V, le=FULL_SCALE_V, allow_inf_nan=False)
    period_s: float | None = Field(None, ge=1e-3, le=3600.0, allow_inf_nan=False)
    duty: float | None = Field(None, gt=0.0, lt=1.0, allow_inf_nan=False)
    """intermittent: the fraction of each period the input is connected (the rest it is open)."""
    bits: int | None = Field(None, ge=1, le=MAX_LOST_BITS)
    """lost_bits: how many of the converter's lowest bits read 0."""
    samples: int | None = Field(None, ge=1, le=MAX_DELAY_SAMPLES)
    other: Literal["AI1", "AI2", "AI3", "AI4"] | None = None
    """short_channels: the A/D input shorted to this one (both read their mean)."""
    limit_v: float | None = Field(None, gt=0.0, le=FULL_SCALE_V, allow_inf_nan=False)
    """saturate: the D/A output's magnitude is clipped at this."""

    @model_validator(mode="after")
    def _consistent(self) -> ChannelFault:
        analog_input = self.channel in AD_CHANNELS
        kinds = AD_KINDS if analog_input else DA_KINDS
        if self.kind not in kinds:
            side = "an A/D input" if analog_input else "a D/A output"
            raise ValueError(f"{self.kind!r} is not a fault of {side} ({self.channel}); allowed: {', '.join(kinds)}")
        if self.end_s is not None and self.end_s <= self.start_s:
            raise ValueError(f"end_s {self.end_s} is not after start_s {self.start_s}")
        needs = _NEEDS.get(self.kind, ())
        missing = [p for p in needs if getattr(self, p) is None]
        if missing:
            raise ValueError(f"a fault of kind {self.kind!r} needs {', '.join(missing)}")
        takes = _TAKES.get(self.kind, frozenset(needs))
        extra = [p for p in _PARAMETERS if getattr(self, p) is not None and p not in takes]
        if extra:
            allowed = ", ".join(sorted(takes)) or "no parameter"
            raise ValueError(f"a fault of kind {self.kind!r} takes {allowed}, not {', '.join(extra)}")
        if self.kind == "stuck" and not analog_input and self.value_v is not None and abs(self.value_v) > FULL_SCALE_V:
            raise ValueError(f"a D/A output is stuck within +-{FULL_SCALE_V:g} V, not {self.value_v}")
        if self.kind == "short_channels" and self.other == self.channel:
            raise ValueError(f"short_channels needs another channel than {self.channel}")
        return self

    @property
    def is_input(self) -> bool:
        """On an A/D input (else on a D/A output)."""
        return self.channel in AD_CHANNELS

    @property
    def index(self) -> int:
        """The channel's index in TPDO1 (A/D) or RPDO1 (D/A) order."""
        return int(self.channel[2]) - 1

    def active(self, time_s: float) -> bool:
        """Whether the fault acts at simulated ``time_s`` (with the scenario's 1 ns tolerance)."""
        return time_s + 1e-9 >= self.start_s and (self.end_s is None or time_s + 1e-9 < self.end_s)

    def describe(self) -> str:
        """One line for the plant's events: channel, kind, its parameters."""
        params = [f"{p}={getattr(self, p)}" for p in _PARAMETERS if getattr(self, p) is not None]
        until = "" if self.end_s is None else f" until {self.end_s:g} s"
        return f"{self.channel} {self.kind}{' ' + ' '.join(params) if params else ''} from {self.start_s:g} s{until}"


def parameter_range(name: str) -> tuple[float, float]:
    """A parameter's range as the schema bounds it (the field's ``ge`` and ``le``)."""
    lo, hi = -math.inf, math.inf
    for m in ChannelFault.model_fields[name].metadata:
        lo = float(getattr(m, "ge", lo))
        hi = float(getattr(m, "le", hi))
    return lo, hi


def size_range(fault: ChannelFault, name: str) -> tuple[float, float]:
    """The range a stimulus profile on ``fault``'s size ``name`` must stay in: the schema's
    bounds (a D/A output's stuck value within the D/A's); ValueError for a size the kind does not take."""
    needs = _NEEDS.get(fault.kind, ())
    takes = _TAKES.get(fault.kind, frozenset(needs))
    if name not in SIZES or name not in takes:
        sizes = ", ".join(p for p in SIZES if p in takes) or "none"
        raise ValueError(f"a fault of kind {fault.kind!r} has no size {name!r}; its sizes a profile may drive: {sizes}")
    lo, hi = parameter_range(name)
    if fault.kind == "stuck" and not fault.is_input:
        lo, hi = max(lo, -FULL_SCALE_V), min(hi, FULL_SCALE_V)
    return lo, hi


class FaultSchedule(BaseModel):
    """The scenario's ``channel_faults`` section: every channel fault of the run."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    faults: tuple[ChannelFault, ...] = ()

    def check_resolution(self, adc_bits: int) -> None:
        """Refuse a ``lost_bits`` that leaves no bit of an ``adc_bits`` converter."""
        for n, fault in enumerate(self.faults):
            if fault.kind == "lost_bits" and fault.bits is not None and fault.bits >= adc_bits:
                raise ValueError(f"channel_faults item {n}: lost_bits {fault.bits} leaves no bit of the {adc_bits}-bit A/D (allowed 1..{adc_bits - 1})")

    def __bool__(self) -> bool:
        return bool(self.faults)
