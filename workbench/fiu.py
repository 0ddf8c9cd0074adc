"""Fault insertion for a user's hardware-in-the-loop test: ``rig.fiu``.

:class:`FaultInsertion` builds the plant's channel faults
(:class:`protocol.channel_faults.ChannelFault`, docs/fault-insertion.md)
one call per fault::

    rig.fiu.short("AI3", to="ground", at_s=5.0, for_s=2.0)
    rig.fiu.noise("AI4", sigma_v=0.05, seed=3, at_s=10.0)
    rig.fiu.saturate("AO1", limit_v=2.0, at_s=12.0, for_s=8.0)

Each is checked at once: a bad channel, kind or value raises
:class:`FaultError`, one line naming the channel, the kind, the value and
what is allowed. Given before the run, the faults join the ``channel_faults``
section of the plant's ``scenario`` setting (:meth:`FaultInsertion.merge`);
during a ``lockstep``/``realtime`` run each is published on the plant's
test port as a ``channel_fault`` scenario command, which the plant adds to
its fault unit on arrival: it acts from its ``at_s`` in simulated time
(from the next sample if that has passed).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, Protocol

from pydantic import ValidationError

from protocol.channel_faults import AD_CHANNELS, ChannelFault
from protocol.messages import ScenarioCommand

__all__ = ["FaultError", "FaultInsertion", "build_fault", "channel_fault_command"]


class FaultError(ValueError):
    """A fault the plant's channels do not have (one line)."""


class _Rig(Protocol):
    @property
    def started(self) -> bool: ...

    def _publish_scenario(self, cmd: ScenarioCommand) -> None: ...


def build_fault(channel: str, kind: str, at_s: float = 0.0, for_s: float | None = None, **params: Any) -> ChannelFault:
    """One checked fault: ``kind`` on ``channel`` from simulated ``at_s`` for ``for_s``
    seconds (None: to the end of the run); raises :class:`FaultError` in one line."""
    given = {k: v for k, v in params.items() if v is not None}
    end = None if for_s is None else at_s + for_s
    if for_s is not None and not for_s > 0:
        raise FaultError(f"{kind} on {channel}: for_s {for_s} must be positive (or None: to the end of the run)")
    try:
        return ChannelFault(channel=channel, kind=kind, start_s=at_s, end_s=end, **given)
    except ValidationError as exc:
        raise FaultError(f"{kind} on {channel}: " + "; ".join(_error_text(e) for e in exc.errors())) from None


def _error_text(error: Any) -> str:
    where = ".".join(map(str, error["loc"]))
    message = str(error["msg"]).removeprefix("Value error, ")
    value = error.get("input")
    shown = f" (got {value!r})" if where and not isinstance(value, dict) else ""
    return f"{where}: {message}{shown}" if where else message


def channel_fault_command(fault: ChannelFault, seq: int = 0) -> ScenarioCommand:
    """The test port's scenario command that adds ``fault`` to a running plant (on arrival)."""
    return ScenarioCommand(seq=seq, sim_time_s=0.0, kind="channel_fault", at_sim_time_s=0.0, channel_fault=fault)


class FaultInsertion:
    """The plant's failure insertion unit, from a test (``rig.fiu``)."""

    def __init__(self, rig: _Rig) -> None:
        self._rig = rig
        self.faults: list[ChannelFault] = []
        """Every fault given before the run, in order (they join the plant's scenario)."""
        self.sent: list[ChannelFault] = []
        """Every fault published on the test port during the run, in order."""

    # -- the kinds ---------------------------------------------------------------------------
    def insert(self, channel: str, kind: str, at_s: float = 0.0, for_s: float | None = None, **params: Any) -> ChannelFault:
        """Any kind by name (docs/fault-insertion.md); the methods below name them."""
        fault = build_fault(channel, kind, at_s, for_s, **params)
        if self._rig.started:
            self._rig._publish_scenario(channel_fault_command(fault, seq=len(self.sent)))
            self.sent.append(fault)
        else:
            self.faults.append(fault)
        return fault

    def short(self, channel: str, to: str = "ground", at_s: float = 0.0, for_s: float | None = None, value_v: float | None = None) -> ChannelFault:
        """A/D input shorted ``to`` ``"ground"`` (0 V), ``"supply"`` (the +15 V rail, or ``value_v``) or another input (``"AI4"``: both read their mean)."""
        if to == "ground":
            return self.insert(channel, "short_ground", at_s, for_s, value_v=value_v)
        if to == "supply":
            return self.insert(channel, "short_supply", at_s, for_s, value_v=value_v)
        if to in AD_CHANNELS:
            return self.insert(channel, "short_channels", at_s, for_s, other=to)
        raise FaultError(f"short on {channel}: to={to!r}; allowed: ground, supply or another input ({', '.join(AD_CHANNELS)})")

    def short_between(self, channel: str, other: str, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        """Two A/D inputs shorted together: both read their mean."""
        return self.insert(channel, "short_channels", at_s, for_s, other=other)

    def open(self, channel: str, at_s: float = 0.0, for_s: float | None = None, value_v: float | None = None) -> ChannelFault:
        """An open wire: an input reads 0 V (or ``value_v``), a valve gets 0 V."""
        return self.insert(channel, "open", at_s, for_s, value_v=value_v)

    def stuck(self, channel: str, at_s: float = 0.0, for_s: float | None = None, value_v: float | None = None) -> ChannelFault:
        """Stuck at the value of the fault's first sample (or ``value_v``)."""
        return self.insert(channel, "stuck", at_s, for_s, value_v=value_v)

    def offset(self, channel: str, offset_v: float, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        return self.insert(channel, "offset", at_s, for_s, offset_v=offset_v)

    def gain(self, channel: str, factor: float, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        return self.insert(channel, "gain", at_s, for_s, factor=factor)

    def noise(self, channel: str, sigma_v: float, seed: int = 0, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        """Gaussian noise of ``sigma_v`` from the fault's own generator (PCG64 seeded with ``seed``)."""
        return self.insert(channel, "noise", at_s, for_s, sigma_v=sigma_v, seed=seed)

    def drift(self, channel: str, rate_v_s: float, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        return self.insert(channel, "drift", at_s, for_s, rate_v_s=rate_v_s)

    def intermittent(
        self, channel: str, period_s: float, duty: float, at_s: float = 0.0, for_s: float | None = None, value_v: float | None = None
    ) -> ChannelFault:
        """Connected for ``duty`` of each ``period_s``, open (0 V or ``value_v``) for the rest."""
        return self.insert(channel, "intermittent", at_s, for_s, period_s=period_s, duty=duty, value_v=value_v)

    def lost_bits(self, channel: str, bits: int, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        """The converter's lowest ``bits`` bits read 0."""
        return self.insert(channel, "lost_bits", at_s, for_s, bits=bits)

    def delay(self, channel: str, samples: int, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        """The value ``samples`` conversions (inputs) or D/A updates (outputs) before."""
        return self.insert(channel, "delay", at_s, for_s, samples=samples)

    def saturate(self, channel: str, limit_v: float, at_s: float = 0.0, for_s: float | None = None) -> ChannelFault:
        """A D/A output clipped to +-``limit_v``."""
        return self.insert(channel, "saturate", at_s, for_s, limit_v=limit_v)

    # -- the plant's scenario ----------------------------------------------------------------
    def merge(self, plant: Mapping[str, Any]) -> dict[str, Any]:
        """The plant's settings with the faults given before the run added to the
        ``channel_faults`` section of its ``scenario`` (unchanged without faults)."""
        out = dict(plant)
        if not self.faults:
            return out
        out["scenario"] = json.dumps(merge_scenario(out.get("scenario"), self.faults))
        return out


def merge_scenario(scenario: Any, faults: list[ChannelFault]) -> dict[str, Any]:
    """A scenario setting (text, a list of commands, a mapping of sections or None) as
    a mapping of sections, with ``faults`` after its own ``channel_faults``."""
    value: Any = scenario
    if isinstance(value, str):
        value = json.loads(value) if value.strip() else {}
    if value is None:
        value = {}
    sections: dict[str, Any] = {"commands": list(value)} if isinstance(value, list) else dict(value)
    own = list(sections.get("channel_faults", []))
    extra = [f.model_dump(mode="json", exclude_none=True) for f in faults]
    sections["channel_faults"] = own + extra
    return sections
