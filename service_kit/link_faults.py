"""Link faults as scripted stimulus: a scenario file and a pure, seeded engine.

A scenario (YAML or JSON, :class:`Scenario`) lists faults, each on one link
(``can`` or ``zenoh``), for some message kinds, active between ``start_s``
and ``stop_s`` on the simulated axis (``time_base: sim``, the default) or on
the wall clock since the run began (``time_base: wall``). A fault may

* add a fixed ``delay_s`` plus a random ``jitter`` (uniform, normal
  truncated at zero, or exponential);
* ``drop`` a message with a probability;
* ``duplicate`` it with a probability;
* ``reorder`` it (let the next one of its kind overtake it) with a probability;
* cut the link in bursts: an ``outage`` of ``length_s`` every ``every_s``
  (every message of the kinds inside a burst is dropped).

Beside the link faults a scenario may freeze the controller's loop
(``stalls``: at a simulated time, for some wall-clock seconds), slow the
DSP board (``dsp_delay_s`` of extra compute time per batch) and make error
frames on the CAN wire (``can_errors``, :class:`CanErrorFault`; a
``ralfwire`` bus only, docs/can-errors.md): the one place every injected
fault of the rig is written.

The engine is pure: the fate of a message is a function of the scenario's
seed, the fault's index, the message kind and the message's own sequence
number (the tick for CAN frames; for zenoh batches and interrupts the tick
the batch went out at), through a counter-based hash (SplitMix64). It keeps no random
state that depends on the order of calls, so a run in lockstep or in the
co-simulation, where the sequence numbers and the simulated time are
deterministic, is reproducible bit for bit, whatever order the messages
arrive in. Where the engine is applied (at the controller's edges, in
simulated ticks): :mod:`controller.fault_stage`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from statistics import NormalDist
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, model_validator

from protocol.bounded_parse import TooLarge, load_json, load_yaml
from protocol.files import read_regular_text

Link = Literal["can", "zenoh"]
CAN_KINDS = ("sync", "tpdo", "rpdo")
"""CAN frames a fault can act on: the controller's SYNC, the plant's TPDO1 (A/D), the controller's RPDO1 (D/A)."""
ZENOH_KINDS = ("batch", "interrupt")
"""zenoh messages a fault can act on: the controller's sample batch, the DSP's interrupt."""
KINDS: dict[str, tuple[str, ...]] = {"can": CAN_KINDS, "zenoh": ZENOH_KINDS}
Seconds = Annotated[float, Field(ge=0.0, le=1e7, allow_inf_nan=False)]
Probability = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]

_MASK = (1 << 64) - 1
_KIND_IDS = {kind: i + 1 for i, kind in enumerate(CAN_KINDS + ZENOH_KINDS)}
_NORMAL = NormalDist()


class Jitter(BaseModel):
    """A random delay added to ``delay_s``: ``uniform`` on ``[low_s, high_s]``,
    ``normal`` with ``mean_s``/``std_s`` (negative draws count as 0),
    ``exponential`` with mean ``scale_s``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    distribution: Literal["uniform", "normal", "exponential"]
    low_s: Seconds = 0.0
    high_s: Seconds = 0.0
    mean_s: Seconds = 0.0
    std_s: Seconds = 0.0
    scale_s: Seconds = 0.0

    @model_validator(mode="after")
    def _consistent(self) -> Jitter:
        if self.distribution == "uniform" and self.high_s < self.low_s:
            raise ValueError("uniform jitter needs low_s <= high_s")
        return self

    def sample(self, u: float) -> float:
        """The delay (s) at quantile ``u`` in (0, 1) (inverse CDF)."""
        if self.distribution == "uniform":
            return self.low_s + u * (self.high_s - self.low_s)
        if self.distribution == "normal":
            return max(0.0, self.mean_s + self.std_s * _NORMAL.inv_cdf(u)) if self.std_s > 0 else self.mean_s
        return -self.scale_s * math.log1p(-u)


class Outage(BaseModel):
    """Burst outages: the link is down for ``length_s`` at the start of every ``every_s``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    every_s: Annotated[float, Field(gt=0.0, le=1e7, allow_inf_nan=False)]
    length_s: Seconds


class LinkFault(BaseModel):
    """One fault on one link, for some message kinds, over a time window."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    link: Link
    kinds: list[str] = Field(min_length=1, max_length=8)
    start_s: Seconds = 0.0
    stop_s: Seconds | None = None
    time_base: Literal["sim", "wall"] = "sim"
    delay_s: Seconds = 0.0
    jitter: Jitter | None = None
    drop: Probability = 0.0
    duplicate: Probability = 0.0
    reorder: Probability = 0.0
    outage: Outage | None = None
    note: Annotated[str, Field(max_length=200)] = ""

    @model_validator(mode="after")
    def _kinds(self) -> LinkFault:
        allowed = KINDS[self.link]
        unknown = [k for k in self.kinds if k not in allowed]
        if unknown:
            raise ValueError(f"{self.link} fault: unknown kinds {unknown}; known: {list(allowed)}")
        if self.stop_s is not None and self.stop_s < self.start_s:
            raise ValueError("stop_s must not be before start_s")
        return self

    def active(self, t: float) -> bool:
        return t >= self.start_s and (self.stop_s is None or t < self.stop_s)

    def in_outage(self, t: float) -> bool:
        o = self.outage
        return o is not None and (t - self.start_s) % o.every_s < o.length_s


class Acceptance(BaseModel):
    """Pass/fail criteria of a timing test (defaults: 200 Hz wake-up p99 <= 250 us,
    p99.9 <= 1 ms, never two deadline misses in a row)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    wakeup_p99_us: Seconds = 250.0
    wakeup_p999_us: Seconds = 1000.0
    max_consecutive_misses: Annotated[int, Field(ge=0, le=10**6)] = 1


class Stall(BaseModel):
    """The controller's loop freezes before the tick at ``at_s`` (simulated time, rounded
    to the tick) for ``wall_s`` seconds of wall-clock time: the plant's SYNC watchdog
    should trip (in real time; in lockstep the plant waits for the next SYNC)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    at_s: Seconds
    wall_s: Annotated[float, Field(ge=0.0, le=60.0, allow_inf_nan=False)]


CAN_ID_MAX = 0x1FFFFFFF
"""The largest (extended, 29-bit) CAN identifier."""


def _can_identifier(value: Any) -> Any:
    """``all``, an integer, or an integer written as text (``"0x181"``, as JSON has no hex literals)."""
    if isinstance(value, str) and value != "all":
        try:
            return int(value, 0)
        except ValueError:
            raise ValueError(f"identifier {value!r} is neither 'all' nor an integer (e.g. 0x181)") from None
    return value


class CanErrorFault(BaseModel):
    """Error frames on the CAN wire (``ralfwire`` only, docs/can-errors.md): attempts of
    frames with ``identifier`` (or ``all``) starting in ``[from_s, to_s)`` fail, every
    ``every``-th of them with ``probability``, at most ``count`` times (and at most
    ``attempts_per_frame`` times per frame); each costs an error
    frame and the frame is retransmitted. Becomes a
    :class:`service_kit.can_wire.arbitration.ErrorInjection`."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    identifier: Annotated[int | Literal["all"], BeforeValidator(_can_identifier)] = "all"
    count: Annotated[int, Field(ge=1, le=10**7)] | None = None
    probability: Probability = 1.0
    every: Annotated[int, Field(ge=1, le=10**6)] = 1
    from_s: Seconds = 0.0
    to_s: Seconds | None = None
    echo_bits: Annotated[int, Field(ge=0, le=6)] = 0
    attempts_per_frame: Annotated[int, Field(ge=1, le=10**6)] | None = None
    """Only each frame's first so many attempts can fail: each frame fails that often, then goes through."""
    note: Annotated[str, Field(max_length=200)] = ""

    @model_validator(mode="after")
    def _bounded(self) -> CanErrorFault:
        if self.identifier != "all" and not 0 <= self.identifier <= CAN_ID_MAX:
            raise ValueError(f"identifier {self.identifier} is outside 0..0x{CAN_ID_MAX:X}")
        if self.to_s is not None and self.to_s <= self.from_s:
            raise ValueError("to_s must be after from_s")
        if self.count is None and self.to_s is None and self.probability == 1.0 and self.every == 1 and self.attempts_per_frame is None:
            raise ValueError("destroys every frame for ever: give count, to_s, attempts_per_frame, a probability below 1 or every above 1")
        return self


class Scenario(BaseModel):
    """A scenario file: the faults, their seed, and (for ``ralf-hil timing-test``) the run and its criteria."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=1, max_length=64)] = "scenario"
    description: Annotated[str, Field(max_length=2000)] = ""
    seed: Annotated[int, Field(ge=0, lt=2**63)] = 0
    faults: list[LinkFault] = Field(default_factory=list, max_length=64)
    stalls: list[Stall] = Field(default_factory=list, max_length=64, description="The controller's loop freezing (wall clock)")
    dsp_delay_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = Field(
        0.0, description="Extra compute time the DSP board takes per batch (a slowed board; 0 = none)"
    )
    can_errors: list[CanErrorFault] = Field(default_factory=list, max_length=64, description="Error frames on the CAN wire (ralfwire only)")
    duration_s: Annotated[float, Field(gt=0.0, le=1e6)] = 10.0
    mode: Literal["cosim", "lockstep", "realtime"] = "cosim"
    settings: dict[str, dict[str, Any]] = Field(default_factory=dict, description="Per service (controller, plant, dsp): settings for the run")
    acceptance: Acceptance = Field(default_factory=Acceptance)


class ScenarioError(ValueError):
    """A scenario file that cannot be read or does not validate."""


def parse_scenario(text: str, *, yaml_ok: bool = True) -> Scenario:
    """A scenario from JSON or YAML text (YAML needs PyYAML)."""
    data: Any
    try:
        data = load_json(text, "the fault scenario")
    except TooLarge as exc:
        raise ScenarioError(str(exc)) from None
    except json.JSONDecodeError:
        if not yaml_ok:
            raise ScenarioError("scenario is not valid JSON") from None
        try:
            import yaml
        except ImportError:  # pragma: no cover - pyyaml comes with the test and campaign extras
            raise ScenarioError("a YAML scenario needs PyYAML (pip install pyyaml); or write it as JSON") from None
        try:
            data = load_yaml(text, "the fault scenario")
        except TooLarge as exc:
            raise ScenarioError(str(exc)) from None
        except yaml.YAMLError as exc:
            raise ScenarioError(f"scenario is neither JSON nor YAML: {exc}") from None
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:  # one line: each error's place and message
        raise ScenarioError("invalid scenario: " + "; ".join(f"{'.'.join(map(str, e['loc'])) or 'scenario'}: {e['msg']}" for e in exc.errors())) from None


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario file (``.json``, ``.yaml``, ``.yml``)."""
    p = Path(path)
    try:
        text = read_regular_text(p)  # a FIFO or device named here must not block the start
    except OSError as exc:
        raise ScenarioError(f"cannot read scenario {p}: {exc}") from None
    return parse_scenario(text, yaml_ok=p.suffix.lower() != ".json")


def scenario_setting(text: str) -> Scenario | None:
    """The scenario a ``fault_scenario`` setting names: inline JSON or a file (None when empty)."""
    text = text.strip()
    if not text:
        return None
    return parse_scenario(text, yaml_ok=False) if text[:1] in ("{", "[") else load_scenario(text)


def _splitmix(x: int) -> int:
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def uniform(seed: int, *key: int) -> float:
    """A uniform number in the open interval (0, 1), a pure function of ``seed`` and ``key``."""
    x = _splitmix(seed & _MASK)
    for part in key:
        x = _splitmix(x ^ (part & _MASK))
    return ((x >> 11) + 0.5) * 2.0**-53


# the independent draws one message gets from one fault
_DRAW_DROP, _DRAW_DUP, _DRAW_REORDER, _DRAW_JITTER = 1, 2, 3, 4


@dataclass(frozen=True)
class Fate:
    """What the faults active at a message do to it."""

    dropped: bool = False
    delay_s: float = 0.0
    copies: int = 1
    """1 normally, 2 when duplicated."""
    reordered: bool = False
    faults: tuple[int, ...] = ()
    """Indices of the faults that acted on the message."""


PASS = Fate()


@dataclass
class FaultCounters:
    """Per kind: messages seen under an active fault, dropped, delayed, duplicated, reordered."""

    seen: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)
    delayed: dict[str, int] = field(default_factory=dict)
    duplicated: dict[str, int] = field(default_factory=dict)
    reordered: dict[str, int] = field(default_factory=dict)

    def add(self, kind: str, fate: Fate) -> None:
        self.seen[kind] = self.seen.get(kind, 0) + 1
        for name, hit in (("dropped", fate.dropped), ("delayed", fate.delay_s > 0), ("duplicated", fate.copies > 1), ("reordered", fate.reordered)):
            if hit:
                table: dict[str, int] = getattr(self, name)
                table[kind] = table.get(kind, 0) + 1

    def as_dict(self) -> dict[str, int]:
        """Flat, for Health counters: ``fault_<action>_<kind>``."""
        out: dict[str, int] = {}
        for action in ("seen", "dropped", "delayed", "duplicated", "reordered"):
            for kind, n in getattr(self, action).items():
                out[f"fault_{action}_{kind}"] = n
        return out


@dataclass(frozen=True)
class FaultEvent:
    """One message a fault acted on, for the record and the report."""

    t_s: float
    kind: str
    seq: int
    dropped: bool
    delay_s: float
    copies: int
    reordered: bool
    faults: tuple[int, ...]


class FaultEngine:
    """Decides each message's :class:`Fate` from the scenario (pure; see the module docstring).

    ``decide`` is called once per message of a faultable kind; a kind no
    fault names costs one dictionary look-up. Every decision that changed
    something is counted and kept as a :class:`FaultEvent` (the first
    ``max_events``)."""

    def __init__(self, scenario: Scenario, max_events: int = 100_000) -> None:
        self.scenario = scenario
        self._by_kind: dict[str, list[tuple[int, LinkFault]]] = {}
        for i, f in enumerate(scenario.faults):
            for kind in f.kinds:
                self._by_kind.setdefault(kind, []).append((i, f))
        self.counters = FaultCounters()
        self.events: list[FaultEvent] = []
        self.max_events = max_events
        self.events_dropped = 0

    def covers(self, kind: str) -> bool:
        """True if any fault names ``kind`` (else ``decide`` always passes it)."""
        return kind in self._by_kind

    @property
    def kinds(self) -> Iterable[str]:
        return self._by_kind.keys()

    def decide(self, kind: str, seq: int, sim_s: float, wall_s: float) -> Fate:
        """The fate of message ``seq`` of ``kind`` sent at ``sim_s`` (simulated) / ``wall_s`` (since the run began)."""
        faults = self._by_kind.get(kind)
        if not faults:
            return PASS
        seed = self.scenario.seed
        kid = _KIND_IDS[kind]
        dropped = reordered = False
        delay = 0.0
        copies = 1
        acting: list[int] = []
        for i, f in faults:
            t = sim_s if f.time_base == "sim" else wall_s
            if not f.active(t):
                continue
            acted = False
            if f.in_outage(t) or (f.drop > 0.0 and uniform(seed, i, kid, seq, _DRAW_DROP) < f.drop):
                dropped = acted = True
            if f.duplicate > 0.0 and uniform(seed, i, kid, seq, _DRAW_DUP) < f.duplicate:
                copies, acted = 2, True
            if f.reorder > 0.0 and uniform(seed, i, kid, seq, _DRAW_REORDER) < f.reorder:
                reordered = acted = True
            d = f.delay_s + (f.jitter.sample(uniform(seed, i, kid, seq, _DRAW_JITTER)) if f.jitter is not None else 0.0)
            if d > 0.0:
                delay += d
                acted = True
            if acted:
                acting.append(i)
        if not acting:
            return PASS
        fate = Fate(
            dropped=dropped, delay_s=0.0 if dropped else delay, copies=1 if dropped else copies, reordered=reordered and not dropped, faults=tuple(acting)
        )
        self.counters.add(kind, fate)
        if len(self.events) < self.max_events:
            self.events.append(FaultEvent(sim_s, kind, seq, fate.dropped, fate.delay_s, fate.copies, fate.reordered, fate.faults))
        else:
            self.events_dropped += 1
        return fate
