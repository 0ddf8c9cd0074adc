"""The plant's run-time parameters (docs/calibration.md, "The plant's
parameters"): the calibration entries of its XCP table
(:data:`plant_emulator.xcp_table.XCP_TABLE`), named ``plant.NAME`` outside
the plant (``plant.payload``), changed on the same path as the controller's
(:mod:`service_kit.param_path`: checked against the table, queued, applied,
recorded as a :class:`~protocol.messages.ParamChanged` on
``plant/param_changes`` and counted).

The plant's step boundary is the SYNC: a change is applied before the model's
step of the next SYNC (:meth:`PlantParams.before_tick` with the SYNC's
index ``k``, from 0; its simulated time ``k * Ts``), so that step already
uses it. A scheduled step (the plant's ``param_schedule`` setting,
``rig.param.set("plant.payload", 1, at_s=2)``) is applied at the first SYNC
``k`` with ``k * Ts >= at_s``: the co-simulation and the lockstep rigs take it
at the same SYNC. Its sources: the plant's XCP slave (kind ``xcp``),
``ralf-hil param set plant.NAME`` (kind ``param``, with the plant's
``param_commands``) and the schedule (kind ``schedule``).

The payload (1: attach the 15.65 lb plate at the tip, 0: release it) is the
one parameter today; a change is also a plant event ``payload``, as a
scenario's command is.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Final

from plant_emulator.plant_model import PlantModel
from plant_emulator.xcp_table import XCP_TABLE, plant_layout
from protocol.param_schedule import ParamStep
from service_kit.param_path import ParamPath, ParamRefused, Pending, Recorder
from service_kit.xcp.memory import Variable, Write
from service_kit.xcp.packets import Err

__all__ = ["BOARD", "PlantParams"]

BOARD: Final = "plant"
"""The prefix of the plant's parameter names (``plant.payload``)."""
_SOURCE: Final = {e.variable.name: e.source for e in XCP_TABLE if e.variable.kind == "calibration"}
"""Each parameter's source in the table (what it sets in the model)."""
_BY: Final = {"xcp": "XCP", "param": "ralf-hil param", "schedule": "the parameter schedule"}


class PlantParams(ParamPath):
    """The plant's parameter path (module docstring)."""

    def __init__(
        self,
        arm: PlantModel,
        period_s: float,
        record: Recorder | None,
        schedule: Sequence[ParamStep] = (),
        *,
        event: Callable[[str, str], None] | None = None,
        counted: bool = False,
        publish: Callable[[bytes], None] | None = None,
    ) -> None:
        self.arm = arm
        self.event = event
        """Tells the plant's events of a change made (``payload``)."""
        super().__init__(BOARD, plant_layout(), period_s, record, schedule, counted=counted, publish=publish)

    def _settable(self, v: Variable) -> bool:
        return _SOURCE.get(v.name) != "payload" or hasattr(self.arm, "payload_attached")

    def value_raw(self, v: Variable) -> float:
        """The payload: 1 attached, 0 not (NaN: a model without one)."""
        if _SOURCE.get(v.name) == "payload" and hasattr(self.arm, "payload_attached"):
            return float(bool(self.arm.payload_attached))
        return math.nan

    def guard(self, changes: Sequence[Write]) -> None:
        for w in changes:
            self.guard_step(w)

    def guard_step(self, w: Write) -> None:
        if not self._settable(w.variable):
            raise ParamRefused(Err.ERR_ACCESS_DENIED, f"this plant model has no {w.variable.name}")

    def apply_changes(self, pending: Pending, tick: int) -> None:
        """The model's parameters set before this SYNC's step (the payload attached or released)."""
        for w in pending.changes:
            if _SOURCE.get(w.variable.name) == "payload":
                attached = bool(w.raw)
                self.arm.attach_payload(attached)
                if self.event is not None:
                    self.event("payload", f"payload {'attached' if attached else 'released'} by {_BY[pending.kind]} at {tick * self.period_s:.3f} s")
