"""The rig's run-time parameters (docs/calibration.md): the registry of the
boards' parameter tables, and a run's scripted changes (``rig.param``).

Each board that serves parameters has one table of
:class:`service_kit.xcp.memory.Variable` (its XCP table: the calibration
entries are its parameters, with their unit, limits and conversion);
:data:`PARAM_TABLES` names them by board, and a parameter outside its board
is ``BOARD.NAME`` (``controller.kp1``, ``plant.payload``). Another board's
table joins with one line here (and its board takes its changes on the shared
path, :mod:`service_kit.param_path`).

::

    rig.param.set("controller.kp1", 8000.0, at_s=2.0)    # mV/rad, from the first tick at or after 2 s

A scripted change goes into its board's ``param_schedule`` setting, which
the board applies at the first step (the controller's tick, the plant's
SYNC) at or after ``at_s`` in simulated time (controller/params.py,
plant_emulator/params.py), so the co-simulation and the lockstep rigs give the
same bits with it; the value is checked against the table here, before the
run (one line, :class:`~protocol.errors.ConfigError`), and by the board again
with its own guards when the run starts.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Final

from controller.xcp_table import XCP_TABLE
from plant_emulator.xcp_table import XCP_TABLE as PLANT_XCP_TABLE
from protocol.errors import ConfigError
from protocol.param_schedule import ParamStep, parse_param_schedule
from service_kit.xcp.memory import Variable

__all__ = ["PARAM_TABLES", "ParamSchedule", "lookup", "parameters"]

PARAM_TABLES: Final[dict[str, Sequence[Any]]] = {
    "controller": XCP_TABLE,
    "plant": PLANT_XCP_TABLE,
}
"""Board -> its table (entries with a ``variable``, or :class:`Variable` s); its calibration entries are its parameters."""


def parameters(board: str) -> dict[str, Variable]:
    """The parameters of ``board``'s table, by name."""
    out: dict[str, Variable] = {}
    for entry in PARAM_TABLES[board]:
        v: Variable = getattr(entry, "variable", entry)
        if v.kind == "calibration":
            out[v.name] = v
    return out


def lookup(name: str) -> tuple[str, Variable]:
    """``(board, parameter)`` of ``BOARD.NAME``; a one-line :class:`ConfigError` naming what exists otherwise."""
    board, _, short = name.partition(".")
    if board not in PARAM_TABLES:
        raise ConfigError(f"parameter {name!r}: no board {board!r} serves parameters (have {', '.join(PARAM_TABLES)})")
    table = parameters(board)
    if short not in table:
        raise ConfigError(f"no parameter {name!r} (known: {', '.join(f'{board}.{n}' for n in table)})")
    return board, table[short]


def check(name: str, value: float) -> tuple[str, Variable]:
    """``name`` and a physical ``value`` against the table: finite and inside the limits."""
    board, v = lookup(name)
    if not (isinstance(value, int | float) and math.isfinite(value) and v.lower <= value <= v.upper):
        raise ConfigError(f"{name} = {value!r} refused: outside its limits {v.lower:g} .. {v.upper:g} {v.unit}".rstrip())
    raw = (float(value) - v.offset) / v.factor
    if v.code in "bBhHiIqQ" and raw != round(raw):
        raise ConfigError(f"{name} = {value!r} refused: not one of its whole steps".rstrip())
    return board, v


class ParamSchedule:
    """A run's scripted parameter changes, given before the run (``rig.param``)."""

    def __init__(self, steps: Iterable[Mapping[str, Any]] = ()) -> None:
        self.steps: list[ParamStep] = []
        self.started = False
        """Set by the rig when its run starts: the schedule is fixed from then on."""
        for step in steps:
            self.set(str(step["name"]), float(step["value"]), at_s=float(step.get("at_s", 0.0)))

    def set(self, name: str, value: float, *, at_s: float = 0.0) -> ParamStep:
        """``name`` (``BOARD.NAME``) to the physical ``value`` (the table's unit) from the first tick at or after ``at_s``."""
        if self.started:
            raise RuntimeError("rig.param.set takes its changes before the run (a running rig: ralf-hil param set, docs/calibration.md)")
        check(name, value)
        if not (math.isfinite(at_s) and at_s >= 0.0):
            raise ConfigError(f"{name}: at_s must be a time at or after 0 s, got {at_s!r}")
        step = ParamStep(name=name, value=float(value), at_s=float(at_s))
        self.steps.append(step)
        return step

    def profiles(self) -> tuple[dict[str, Any], ...]:
        """The steps as plain mappings (a :class:`~workbench.rig_spec.RigSpec`'s ``params``)."""
        return tuple(s.model_dump() for s in self.steps)

    def board_schedule(self, board: str, given: str | list[Any] | None = None) -> str | None:
        """``board``'s ``param_schedule`` setting: ``given`` (the setting the run has already) then the steps
        on ``board``'s parameters; None when both are empty."""
        own = [s.model_dump() for s in parse_param_schedule(given)] if given else []
        mine = [s.model_dump() for s in self.steps if s.name.partition(".")[0] == board]
        return json.dumps(own + mine) if own or mine else None

    def boards(self) -> frozenset[str]:
        return frozenset(s.name.partition(".")[0] for s in self.steps)

    def __len__(self) -> int:
        return len(self.steps)
