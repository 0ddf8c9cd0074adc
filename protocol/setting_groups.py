"""Settings that travel as one structured value: the OATF's tuning, the valve
dither, the PI gains, the controller's timeouts and its fault policies, the
DSP's spectral smoothing.

Each group is a frozen pydantic model whose fields keep their defaults unless
named, so ``RALF_POLICIES=deadline=stop`` changes one policy and leaves the
other four as they were. A group is given as

* ``KEY=VALUE`` pairs separated by commas (a pair's value may itself hold a
  comma, as a band does: ``band_hz=2,7,amplitude_v=0.01``);
* a JSON object (``{"band_hz": [2, 7], "amplitude_v": 0.01}``);
* or, from Python, a dict or the model itself.
"""

from __future__ import annotations

import json
import re
from typing import Annotated, Any, Literal, Self

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, field_validator

from protocol.bounded_parse import load_json

Hz = Annotated[float, Field(ge=0.01, le=2500)]
Policy = Literal["count", "warn", "degrade", "stop"]

MAX_CPU = 4095


def parse_cpus(text: str) -> tuple[int, ...]:
    """``"1"``, ``"0,1"`` or ``"0-1"`` -> CPU numbers; empty -> ()."""
    cpus: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        lo, sep, hi = part.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()):
            raise ValueError(f"cpus {text!r}: expected CPU numbers like 1 or 0,1 or 0-1")
        first, last = int(lo), int(hi) if sep else int(lo)
        if last < first or last > MAX_CPU:
            raise ValueError(f"cpus {text!r}: {part} is not a range of CPU numbers 0..{MAX_CPU}")
        cpus.extend(range(first, last + 1))
    return tuple(sorted(set(cpus)))


_PAIR_START = re.compile(r",\s*(?=[A-Za-z_]\w*\s*=)")


def parse_group_text(text: str) -> dict[str, Any]:
    """``KEY=VALUE,KEY=VALUE`` or a JSON object -> a dict of raw values (validated by the group's model)."""
    text = text.strip()
    if not text:
        return {}
    if text.startswith("{"):
        try:
            data = load_json(text, "the group's JSON object")
        except json.JSONDecodeError as exc:
            raise ValueError(f"not a JSON object: {exc}") from None
        if not isinstance(data, dict):
            raise ValueError("expected a JSON object")
        return data
    out: dict[str, Any] = {}
    for pair in _PAIR_START.split(text):
        key, sep, value = pair.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"{pair!r} is not KEY=VALUE (e.g. deadline=stop,stale=warn)")
        if key in out:
            raise ValueError(f"{key} is given twice")
        out[key] = value.strip()
    return out


def band_text(value: Any) -> Any:
    """A pair given as text (a frequency band, a gain per joint): a JSON array ``"[1, 20]"`` or a plain pair ``"1,20"``."""
    if isinstance(value, str):
        text = value.strip()
        if text.startswith("[") or text.startswith("("):
            text = text[1:-1] if text[-1:] in "])" else text[1:]
        return tuple(part.strip() for part in text.split(","))
    return value


Band = Annotated[tuple[Hz, Hz], BeforeValidator(band_text)]
"""A frequency band, LOW,HIGH in Hz, given as a pair or as text (:func:`band_text`)."""


def _ordered(name: str, value: tuple[float, float]) -> tuple[float, float]:
    if not value[0] < value[1]:
        raise ValueError(f"the {name} band must run from a lower to a higher frequency, got {value[0]:g}, {value[1]:g}")
    return value


def _text(value: Any) -> str:
    """A group's value as text :func:`parse_group_text` reads back exactly (floats by ``repr``)."""
    if isinstance(value, tuple):
        return ",".join(_text(v) for v in value)
    if isinstance(value, bool):
        return str(value).lower()
    return repr(value) if isinstance(value, float) else str(value)


class SettingGroup(BaseModel):
    """A structured setting (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __str__(self) -> str:
        """``KEY=VALUE,...`` of every field (None left out), read back by :func:`parse_group_text`."""
        parts = []
        for name, value in self:
            if value is None:
                continue
            parts.append(f"{name}={_text(value)}")
        return ",".join(parts)

    @classmethod
    def coerce(cls, value: Any) -> Any:
        """A field validator's ``mode="before"`` step: text to a dict of raw values."""
        return parse_group_text(value) if isinstance(value, str) else value

    @classmethod
    def read(cls, value: Any) -> Self:
        """The group from a setting's value as given (text, a dict, the model; None: the defaults)."""
        return cls.model_validate({} if value is None else cls.coerce(value))


class OatfTuning(SettingGroup):
    """The OATF input shaper's design and adaptation (thesis §4.1); its mode stays ``oatf_mode``."""

    location: Literal["outer", "inner"] = Field("outer", description="OATF on the set-points (outer) or actuator commands (inner)")
    frequency_hz: float = Field(4.4, ge=0.1, le=2500, description="Design frequency (the initial value when adaptive)")
    damping: float = Field(0.09, ge=0, lt=1, description="Design damping ratio")
    delay_s: float | None = Field(None, ge=0.001, le=10, description="Fixed delay T1 (default: robust pi/omega_d)")
    band_hz: Band = Field((1.0, 20.0), description="Plausible band of identified frequencies")
    min_confidence: float = Field(0.2, ge=0, le=1, description="Ignore estimates less confident than this (the DSP's confidence)")
    max_stages: int = Field(1, ge=1, le=4, description="Stages: 1 = first mode only (the thesis); more = one per confident extra pole, with hysteresis")
    adapt_damping: bool = Field(False, description="Adaptive: also adapt each stage's design damping to the identified one")
    fallback: Literal["last", "fixed"] = Field("last", description="While degraded: freeze the last good design, or return to frequency_hz")

    @field_validator("band_hz")
    @classmethod
    def _band_order(cls, value: tuple[float, float]) -> tuple[float, float]:
        return _ordered("OATF's plausible", value)


class DitherTuning(SettingGroup):
    """Persistent excitation: a multisine added to each valve command before the D/A, for the identifier (docs/identification.md)."""

    amplitude_v: float = Field(0.0, ge=0, le=2.0, description="RMS (V) of the multisine (0 = off)")
    band_hz: Band = Field((2.0, 7.0), description="Its band: every bin of its period in this range")
    seed: int = Field(0, ge=0, le=2**31 - 1, description="Seed of its random phases (each valve its own)")

    @field_validator("band_hz")
    @classmethod
    def _band_order(cls, value: tuple[float, float]) -> tuple[float, float]:
        return _ordered("dither", value)


class RealtimeMeasures(SettingGroup):
    """The loop thread's real-time measures (service_kit/realtime.py), each applied where permitted."""

    priority: int = Field(0, ge=0, le=99, description="Run the loop thread under SCHED_FIFO at this priority (0 = normal scheduler)")
    cpus: str = Field("", max_length=256, description="Pin the loop thread to these CPUs, e.g. 1, 0,1 or 0-1 (empty = not pinned)")
    cpu_latency_us: int = Field(
        -1,
        ge=-1,
        le=1_000_000,
        description="Hold the CPUs' wake-up latency within this many us through PM QoS (/dev/cpu_dma_latency); 0 = idle CPUs poll (-1 = off)",
    )

    @field_validator("cpus")
    @classmethod
    def _cpu_list(cls, value: str) -> str:
        parse_cpus(value)  # refused here, before any bus or session opens
        return value


class UdpCanOptions(SettingGroup):
    """How the ``udp_multicast`` CAN interface sends (service_kit/transport.py, service_kit/can_udp.py)."""

    ttl: int = Field(
        0, ge=0, le=32, description="IP multicast TTL of CAN frames (0 = never leaves this host; 1 = the local network, e.g. docker compose or a LAN)"
    )
    own_frame_filter: bool = Field(
        True,
        description="Send from a socket of our own and drop our own frames in the kernel (service_kit/can_udp.py); false: python-can's stock bus, which reads them back",
    )


Gain = Annotated[float, Field(ge=0, le=1e6)]
JointGains = Annotated[tuple[Gain, Gain], BeforeValidator(band_text)]
"""A gain per joint, JOINT1,JOINT2, given as a pair or as text (:func:`band_text`)."""


class PiGains(SettingGroup):
    """The two joints' PI gains (thesis §4, controller/pi.py), in the thesis's units."""

    kp_mv_per_rad: JointGains = Field(
        (7500.0, 6250.0), description="Proportional gain per joint, mV of valve voltage per rad of angle error (thesis: 7500,6250)"
    )
    ki_mv_per_rad: JointGains = Field((5000.0, 4166.0), description="Integral gain per joint, on the windowed sum of e*Ts (thesis: 5000,4166)")


class Timeouts(SettingGroup):
    """How long the controller waits before it declares a fault or a stale estimate (docs/timing.md)."""

    startup_s: float = Field(60.0, ge=0.1, le=600, description="Before tick 0: wall time to wait for the plant node and the DSP to answer")
    lockstep_s: float = Field(
        60.0, ge=0.1, le=600, description="Lockstep: wall time to wait for the plant or the DSP before declaring a fault (a starved host is slow, not faulty)"
    )
    plant_heartbeat_s: float = Field(1.0, ge=0.01, le=60, description="Plant heartbeat older than this is a fault (lockstep: at least lockstep_s)")
    stale_after_s: float = Field(2.0, ge=0.01, le=3600, description="Parameters older than this are stale")
    dsp_deadline_s: float | None = Field(None, ge=0.001, le=60, description="Interrupt deadline after a batch (default: the batch period)")


class Smoothing(SettingGroup):
    """The DSP's Savitzky-Golay smoothing of the spectra across frequency bins (docs/identification.md)."""

    window: int = Field(17, ge=0, le=1025, description="Window in bins, odd (0 = off)")
    order: int = Field(2, ge=0, le=10, description="Polynomial order, below the window")


class Policies(SettingGroup):
    """What the controller does on each monitored event (controller/monitors.py): count it, warn, degrade or stop."""

    deadline: Policy = Field("warn", description="An interrupt past its deadline")
    stale: Policy = Field("degrade", description="Parameters older than the timeouts' stale_after_s")
    dsp_lost: Policy = Field("degrade", description="The DSP's liveliness token vanishing")
    overrun: Policy = Field("count", description="A tick finishing after the next was due")
    can_conflict: Policy = Field("stop", description="Another master's SYNC, NMT, RPDO1 or SDO write, or forged plant frames, on the CAN bus")
    can_error_passive: Policy = Field(
        "count", description="A CAN node not error active: the plant's EMCY 0x8120/0x8140 until its error reset, or the controller's own bus (ralfwire)"
    )

    input_range: Policy = Field("stop", description="An input out of its sensor's range or at the converter's clip code (when input_monitors turns it on)")
    input_stuck: Policy = Field("stop", description="An input's code unchanged for stuck_samples ticks while the set-point moves (when on)")
    input_rate: Policy = Field("stop", description="An input changing faster than its rate limit (when on)")
    input_disagree: Policy = Field("stop", description="A measured deflection far from the sag the measured joints imply (when on)")

    def as_dict(self) -> dict[str, Policy]:
        return {name: getattr(self, name) for name in type(self).model_fields}


EXTENSION_LIMIT_IN = 100.0
"""The largest extension (in) a monitor's range may name: five times the cylinders' 20-in stroke."""


class InputMonitors(SettingGroup):
    """Plausibility checks on the controller's A/D inputs (controller/input_monitors.py,
    docs/fault-insertion.md); each is off unless named, its policy is ``policies.input_*``."""

    range: bool = Field(False, description="Check each input against its sensor's range and the converter's clip codes")
    stuck: bool = Field(False, description="Check that each input's code changes while the set-point moves")
    rate: bool = Field(False, description="Check each input's change per tick against its rate limit")
    disagree: bool = Field(False, description="Check the measured deflections against the sag the measured joint angles imply")
    extension_range_in: Annotated[tuple[float, float], BeforeValidator(band_text)] = Field(
        (0.0, 20.0), description="The cylinders' extensions (in) a sound sensor reads: their stroke"
    )
    stuck_samples: int = Field(20, ge=2, le=100_000, description="Ticks with an unchanged code while the set-point moves before stuck fires")
    extension_rate_v_s: float = Field(20.0, ge=0.1, le=1e6, description="Rate limit of the extension inputs AI1, AI2 (V/s; 1 V/in)")
    deflection_rate_v_s: float = Field(100.0, ge=0.1, le=1e6, description="Rate limit of the deflection inputs AI3, AI4 (V/s)")
    disagree_in: float = Field(0.3, ge=0.001, le=10, description="Largest |measured - implied| deflection (in) before disagree fires")

    @field_validator("extension_range_in")
    @classmethod
    def _ordered(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not value[0] < value[1]:
            raise ValueError(f"extension_range_in {value[0]:g},{value[1]:g}: the low end must be below the high end")
        if not (-EXTENSION_LIMIT_IN <= value[0] and value[1] <= EXTENSION_LIMIT_IN):
            raise ValueError(f"extension_range_in {value[0]:g},{value[1]:g}: each end must be within ±{EXTENSION_LIMIT_IN:g} in")
        return value

    @property
    def any(self) -> bool:
        """Whether any check is on."""
        return self.range or self.stuck or self.rate or self.disagree


def describe_group(group: type[SettingGroup]) -> str:
    """One line per key of ``group``: ``key (default): description``."""
    lines = []
    for name, field in group.model_fields.items():
        shown = "-" if field.default is None else _text(field.default)
        lines.append(f"{name} ({shown}): {field.description}")
    return "; ".join(lines)
