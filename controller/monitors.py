"""What the controller does when a timing monitor fires.

Each monitor (``deadline``: an interrupt later than its deadline;
``stale``: no fresh estimate for ``stale_after_s``; ``dsp_lost``: the DSP's
liveliness token vanished; ``overrun``: a tick finished after the next was
due; ``can_conflict``: another master on the CAN bus, i.e. a SYNC, NMT
command, RPDO1 or SDO write this controller did not send, the plant's
SYNC_CONFLICT / RPDO_CONFLICT emergency, or frames forged on the plant's
COB-IDs (a second TPDO1 per SYNC, a heartbeat or EMCY the plant disowns),
see :mod:`controller.plant_link`; its default policy is ``stop``; and, when
the ``input_monitors`` setting turns them on, the plausibility checks on the
A/D inputs of :mod:`controller.input_monitors`; ``can_error_passive``: the
plant node reports itself CAN error passive or recovered from bus off by
EMCY, or the controller's own bus is not error active, see
:mod:`controller.can_errors`, default policy ``count``) has a policy:

* ``count``: count it, nothing else;
* ``warn``: count it and log a warning (once per episode);
* ``degrade``: as warn, and run on the fallback parameters until the
  condition clears (the OATF tuning's ``fallback``: keep the last good design frozen,
  or return to the fixed design frequency);
* ``stop``: end the run with an error.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Literal

Policy = Literal["count", "warn", "degrade", "stop"]
MONITORS = ("deadline", "stale", "dsp_lost", "overrun", "can_conflict")
CAN_ERROR_MONITORS = ("can_error_passive",)
"""A CAN node not error active (:mod:`controller.can_errors`): counted only in a
run that sees one, so runs without CAN error states keep their counters."""
INPUT_MONITORS = ("input_range", "input_stuck", "input_rate", "input_disagree")
"""The plausibility checks on the A/D inputs (:mod:`controller.input_monitors`):
counted only in a run that turns them on (``input_monitors``)."""

log = logging.getLogger(__name__)


class MonitorStop(RuntimeError):
    """A monitor whose policy is ``stop`` fired."""


@dataclass
class Monitors:
    """Counts episodes per monitor and applies its policy."""

    policies: dict[str, Policy]
    episodes: dict[str, int] = field(default_factory=lambda: {m: 0 for m in MONITORS})
    active: set[str] = field(default_factory=set)
    last: str | None = None

    def __post_init__(self) -> None:
        unknown = set(self.policies) - set(MONITORS) - set(INPUT_MONITORS) - set(CAN_ERROR_MONITORS)
        if unknown:
            raise ValueError(f"unknown monitors {sorted(unknown)}; known: {MONITORS + INPUT_MONITORS + CAN_ERROR_MONITORS}")

    @property
    def degraded(self) -> bool:
        """True while a monitor with policy ``degrade`` is firing."""
        if not self.active:  # the per-tick case: nothing firing
            return False
        return any(self.policies.get(m) == "degrade" for m in self.active)

    def fire(self, monitor: str, detail: str) -> None:
        """A new episode of ``monitor``; raises :class:`MonitorStop` under ``stop``."""
        policy = self.policies.get(monitor, "count")
        self.episodes[monitor] = self.episodes.get(monitor, 0) + 1
        self.last = f"{monitor}: {detail}"
        if policy in ("warn", "degrade", "stop") and monitor not in self.active:
            log.warning("%s (policy %s)", self.last, policy)
        self.active.add(monitor)
        if policy == "stop":
            raise MonitorStop(self.last)

    def clear(self, monitor: str) -> None:
        if monitor in self.active:
            self.active.discard(monitor)
            if self.policies.get(monitor) in ("warn", "degrade"):
                log.info("%s cleared", monitor)
