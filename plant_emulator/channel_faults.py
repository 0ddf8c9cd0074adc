"""Faults on the node's signal channels, between the model and the A/D and
between the D/A and the model: what a failure insertion unit does to the
wires of a real board.

:class:`ChannelFaultUnit` is pure and deterministic: each call gets the
simulated time and the true signals and returns the faulted ones, and the
only randomness (``noise``) comes from each fault's own seeded generator, one
deviate per sample while it acts. The plant's application
(:class:`plant_emulator.service.PlantApplication`) calls it on every SYNC
(:meth:`ChannelFaultUnit.convert`: the four A/D voltages to TPDO1's codes)
and on every D/A update (:meth:`ChannelFaultUnit.drive`: the two valve
voltages), only when the schedule has faults of that side; without a
schedule the node's path is untouched.

Order on an A/D input, each stage acting on what the one before left
(faults of one kind in the order of the schedule)::

    true volts -> short_channels -> gain -> offset -> drift -> noise
               -> delay -> stuck -> intermittent -> open -> short_ground
               -> short_supply -> converter (round, clip, saturation flag)
               -> lost_bits -> TPDO1 code

Order on a D/A output::

    D/A volts -> delay -> stuck -> gain -> offset -> saturate -> open -> valve
"""

from __future__ import annotations

import math
from array import array
from collections import deque
from dataclasses import dataclass, field
from typing import Final

import numpy as np
import numpy.typing as npt

from protocol.can_map import ConverterScale
from protocol.channel_faults import DEFAULT_OPEN_V, DEFAULT_SUPPLY_V, ChannelFault, FaultSchedule

__all__ = ["AD_ORDER", "DA_ORDER", "ChannelFaultUnit", "ChannelRecord", "Transition"]

AD_ORDER: Final[tuple[str, ...]] = (
    "short_channels",
    "gain",
    "offset",
    "drift",
    "noise",
    "delay",
    "stuck",
    "intermittent",
    "open",
    "short_ground",
    "short_supply",
)
"""The A/D stages before the converter, in the order they act (``lost_bits`` acts on the code after it)."""
DA_ORDER: Final[tuple[str, ...]] = ("delay", "stuck", "gain", "offset", "saturate", "open")
"""The D/A stages, in the order they act."""


@dataclass
class _State:
    """What one fault remembers while it acts."""

    fault: ChannelFault
    generator: np.random.Generator | None = None
    held: float | None = None
    line: deque[float] | None = None
    active: bool = False
    sizes: dict[str, float] = field(default_factory=dict)
    """Sizes a stimulus profile replaces now (:meth:`ChannelFaultUnit.set_size`)."""


@dataclass
class Transition:
    """A fault inserted (``inserted``) or removed at ``time_s``."""

    time_s: float
    fault: ChannelFault
    inserted: bool


@dataclass
class ChannelRecord:
    """Every conversion and D/A update made while a schedule was set: the true
    values beside the faulted ones (kept in the plant's truth record)."""

    ad_time_s: array[float] = field(default_factory=lambda: array("d"))
    ad_true_v: array[float] = field(default_factory=lambda: array("d"))
    ad_faulted_v: array[float] = field(default_factory=lambda: array("d"))
    ad_codes: array[int] = field(default_factory=lambda: array("q"))
    ad_saturated: array[int] = field(default_factory=lambda: array("b"))
    da_time_s: array[float] = field(default_factory=lambda: array("d"))
    da_commanded_v: array[float] = field(default_factory=lambda: array("d"))
    da_applied_v: array[float] = field(default_factory=lambda: array("d"))

    def arrays(self) -> dict[str, npt.NDArray[np.generic]]:
        """As arrays for the truth file: ``ad_*`` one row per conversion (4 columns), ``da_*`` one per D/A update (2)."""
        return {
            "channel_ad_time_s": np.frombuffer(self.ad_time_s, dtype=np.float64).copy(),
            "channel_ad_true_v": np.frombuffer(self.ad_true_v, dtype=np.float64).reshape(-1, 4).copy(),
            "channel_ad_faulted_v": np.frombuffer(self.ad_faulted_v, dtype=np.float64).reshape(-1, 4).copy(),
            "channel_ad_codes": np.frombuffer(self.ad_codes, dtype=np.int64).reshape(-1, 4).copy(),
            "channel_ad_saturated": np.frombuffer(self.ad_saturated, dtype=np.int8).reshape(-1, 4).astype(np.bool_),
            "channel_da_time_s": np.frombuffer(self.da_time_s, dtype=np.float64).copy(),
            "channel_da_commanded_v": np.frombuffer(self.da_commanded_v, dtype=np.float64).reshape(-1, 2).copy(),
            "channel_da_applied_v": np.frombuffer(self.da_applied_v, dtype=np.float64).reshape(-1, 2).copy(),
        }


class ChannelFaultUnit:
    """The fault schedule's faults, applied to the A/D conversions and D/A updates they act on."""

    def __init__(self, schedule: FaultSchedule, keep_record: bool = True) -> None:
        self.schedule = schedule
        self.keep_record = keep_record
        """Keep every conversion and D/A update in :attr:`record` (the plant does when it writes a truth file)."""
        self._states = [_state(f) for f in schedule.faults]
        self.record = ChannelRecord()
        self._seen = [False] * len(self._states)
        self._ended = [False] * len(self._states)
        self.last_conversion: tuple[float, list[float], list[float], list[bool]] | None = None
        """The last A/D conversion: time, true volts, faulted volts, saturation flags (the live channel truth)."""
        self.last_update: tuple[float, tuple[float, float], tuple[float, float]] | None = None
        """The last D/A update: time, commanded volts, applied volts (the live channel truth)."""
        self._sort()

    def _sort(self) -> None:
        """The faults by stage, in schedule order within each."""
        self._ad = [[s for s in self._states if s.fault.is_input and s.fault.kind == kind] for kind in AD_ORDER]
        self._lost_bits = [s for s in self._states if s.fault.kind == "lost_bits"]
        self._da = [[s for s in self._states if not s.fault.is_input and s.fault.kind == kind] for kind in DA_ORDER]
        self.on_inputs = any(s.fault.is_input for s in self._states)
        """Faults on the A/D inputs: TPDO1's codes come from :meth:`convert`."""
        self.on_outputs = any(not s.fault.is_input for s in self._states)
        """Faults on the D/A outputs: the valves get :meth:`drive`'s voltages."""

    def add(self, fault: ChannelFault) -> None:
        """One more fault, after those of the schedule (a test port's ``channel_fault``
        command): it acts from its ``start_s``, or from the next sample if that has passed."""
        self.schedule = FaultSchedule(faults=(*self.schedule.faults, fault))
        self._states.append(_state(fault))
        self._seen.append(False)
        self._ended.append(False)
        self._sort()

    def set_size(self, index: int, size: str, value: float | None) -> None:
        """Fault ``index``'s parameter ``size`` reads ``value`` from now on (a stimulus profile's,
        docs/stimulus.md); None: its own value again."""
        sizes = self._states[index].sizes
        if value is None:
            sizes.pop(size, None)
        else:
            sizes[size] = value

    def acting(self, time_s: float) -> list[ChannelFault]:
        """The faults whose interval holds ``time_s``, in schedule order."""
        return [s.fault for s in self._states if s.fault.active(time_s)]

    def transitions(self, time_s: float) -> list[Transition]:
        """The faults that started or ended by ``time_s`` since the last call, in schedule order."""
        out: list[Transition] = []
        for n, s in enumerate(self._states):
            f = s.fault
            if not self._seen[n] and time_s + 1e-9 >= f.start_s:
                self._seen[n] = True
                out.append(Transition(f.start_s, f, True))
            if self._seen[n] and not self._ended[n] and f.end_s is not None and time_s + 1e-9 >= f.end_s:
                self._ended[n] = True
                out.append(Transition(f.end_s, f, False))
        return out

    def convert(self, time_s: float, true_v: list[float], scale: ConverterScale) -> tuple[list[int], list[bool]]:
        """The four A/D inputs' true voltages at ``time_s`` through the active faults and the converter: TPDO1's codes and saturation flags."""
        v = [float(x) for x in true_v]
        for stage in self._ad:
            for s in stage:
                if _acting(s, time_s):
                    _input_stage(s, v, time_s)
        codes, flags = scale.quantize_floats(v)
        for s in self._lost_bits:
            if _acting(s, time_s):
                i = s.fault.index
                n = min(int(s.fault.bits or 0), scale.bits - 1)
                codes[i] = (codes[i] >> n) << n
        self.last_conversion = (time_s, true_v, v, flags)
        if self.keep_record:
            self._keep_conversion(time_s, true_v, v, codes, flags)
        return codes, flags

    def _keep_conversion(self, time_s: float, true_v: list[float], v: list[float], codes: list[int], flags: list[bool]) -> None:
        rec = self.record
        rec.ad_time_s.append(time_s)
        rec.ad_true_v.extend(true_v)
        rec.ad_faulted_v.extend(v)
        rec.ad_codes.extend(codes)
        rec.ad_saturated.extend(int(b) for b in flags)

    def drive(self, time_s: float, volts0: float, volts1: float) -> tuple[float, float]:
        """The two D/A voltages at ``time_s`` through the active faults: what the valves see."""
        v = [float(volts0), float(volts1)]
        for stage in self._da:
            for s in stage:
                if _acting(s, time_s):
                    _output_stage(s, v)
        self.last_update = (time_s, (float(volts0), float(volts1)), (v[0], v[1]))
        if self.keep_record:
            rec = self.record
            rec.da_time_s.append(time_s)
            rec.da_commanded_v.extend((float(volts0), float(volts1)))
            rec.da_applied_v.extend(v)
        return v[0], v[1]


def _state(fault: ChannelFault) -> _State:
    """A fault's state; a ``noise`` fault's generator seeded with its ``seed``."""
    return _State(fault, np.random.Generator(np.random.PCG64(fault.seed)) if fault.kind == "noise" else None)


def _acting(s: _State, time_s: float) -> bool:
    """Whether ``s`` acts at ``time_s``; leaving its interval forgets what it held."""
    on = s.fault.active(time_s)
    if not on and s.active:
        s.held, s.line = None, None
    s.active = on
    return on


def _size(s: _State, name: str) -> float | None:
    """The fault's parameter ``name``: a stimulus profile's value while one replaces it, else the fault's own."""
    value = s.sizes.get(name) if s.sizes else None
    return value if value is not None else getattr(s.fault, name)


def _delayed(s: _State, x: float) -> float:
    """The value ``samples`` calls ago (the value at the fault's start until that many have passed)."""
    n = int(s.fault.samples or 1)
    if s.line is None:
        s.line = deque([x] * n)
    s.line.append(x)
    return s.line.popleft()


def _input_stage(s: _State, v: list[float], time_s: float) -> None:
    f = s.fault
    i = f.index
    kind = f.kind
    if kind == "short_channels":
        j = int(str(f.other)[2]) - 1
        mean = (v[i] + v[j]) / 2.0
        v[i] = v[j] = mean
    elif kind == "gain":
        v[i] = v[i] * float(_size(s, "factor") or 0.0)
    elif kind == "offset":
        v[i] = v[i] + float(_size(s, "offset_v") or 0.0)
    elif kind == "drift":
        v[i] = v[i] + float(_size(s, "rate_v_s") or 0.0) * (time_s - f.start_s)
    elif kind == "noise":
        assert s.generator is not None
        v[i] = v[i] + float(_size(s, "sigma_v") or 0.0) * float(s.generator.standard_normal())
    elif kind == "delay":
        v[i] = _delayed(s, v[i])
    elif kind == "stuck":
        if s.held is None:
            s.held = v[i] if f.value_v is None else f.value_v
        v[i] = s.held if "value_v" not in s.sizes else s.sizes["value_v"]
    elif kind == "intermittent":
        period = float(f.period_s or 1.0)
        if math.fmod(time_s - f.start_s, period) >= float(f.duty or 0.0) * period:
            value = _size(s, "value_v")
            v[i] = DEFAULT_OPEN_V if value is None else value
    elif kind == "open":
        value = _size(s, "value_v")
        v[i] = DEFAULT_OPEN_V if value is None else value
    elif kind == "short_ground":
        v[i] = 0.0
    elif kind == "short_supply":
        value = _size(s, "value_v")
        v[i] = DEFAULT_SUPPLY_V if value is None else value


def _output_stage(s: _State, v: list[float]) -> None:
    f = s.fault
    i = f.index
    kind = f.kind
    if kind == "delay":
        v[i] = _delayed(s, v[i])
    elif kind == "stuck":
        if s.held is None:
            s.held = v[i] if f.value_v is None else f.value_v
        v[i] = s.held if "value_v" not in s.sizes else s.sizes["value_v"]
    elif kind == "gain":
        v[i] = v[i] * float(_size(s, "factor") or 0.0)
    elif kind == "offset":
        v[i] = v[i] + float(_size(s, "offset_v") or 0.0)
    elif kind == "saturate":
        limit = float(f.limit_v or 0.0)
        v[i] = limit if v[i] > limit else (-limit if v[i] < -limit else v[i])
    elif kind == "open":
        v[i] = 0.0
