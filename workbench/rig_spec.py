"""A rig run as data: :class:`RigSpec`, frozen and picklable, for runs fanned out
to campaign workers (:func:`workbench.campaign.rigs.map_rigs`) or kept in a list;
:meth:`RigSpec.rig` (or :meth:`workbench.hil.HilRig.from_spec`) makes the
:class:`~workbench.hil.HilRig` that runs it."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workbench.laps import lap_seconds
from workbench.rig_record import Clock

__all__ = ["RigSpec"]


@dataclass(frozen=True)
class RigSpec:
    """One run: its name (the file stem of its outputs), the rig's clock and layout,
    each service's settings, a fault scenario, how long, and where its files go."""

    name: str
    controller: Mapping[str, Any] = field(default_factory=dict)
    plant: Mapping[str, Any] = field(default_factory=dict)
    dsp: Mapping[str, Any] = field(default_factory=dict)
    common: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    """Free text for tables and figures."""
    clock: Clock = "cosim"
    processes: bool = False
    """``lockstep``/``realtime``: the three services as separate processes (else composed in one)."""
    faults: str | Mapping[str, Any] | None = None
    duration_s: float | None = None
    """Simulated seconds (else the controller's ``duration_s`` or ``repeats`` laps)."""
    outputs: Path | None = None
    """Where the run's files go (see :class:`~workbench.hil.HilRig`); None: none kept."""
    mcap: bool = False
    """Record the run into ``<outputs>/<name>.mcap``."""
    meta: Mapping[str, Any] = field(default_factory=dict)
    """Extra facts for the recording's run record (e.g. ``{"experiment": ...}``)."""
    timeout_s: float | None = None
    """Three processes: the wall-clock allowance (default from the expected simulated time)."""
    stimulus: tuple[Mapping[str, Any], ...] = ()
    """Stimulus profiles on the rig's inputs (:mod:`workbench.stimulus`: ``tuple(Stimulus().step(...).profiles)``)."""
    params: tuple[Mapping[str, Any], ...] = ()
    """Scripted parameter changes (:mod:`workbench.params`: ``rig.param.profiles()``), each ``name``, ``value``, ``at_s``."""

    def expected_sim_s(self) -> float:
        """Simulated seconds the run lasts (``duration_s``, the controller's, or its repeats laps)."""
        if self.duration_s is not None:
            return float(self.duration_s)
        c = self.controller
        if c.get("duration_s") is not None:
            return float(c["duration_s"])
        repeats = int(c.get("repeats", 0))
        if repeats <= 0:
            raise ValueError(f"run {self.name!r}: set duration_s, or the controller's duration_s or repeats")
        return repeats * lap_seconds(float(c.get("tip_speed_in_s", 5.0)), c.get("trajectory") or None)
