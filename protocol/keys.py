"""zenoh key expressions. Everything of one rig lives under ``ralf/<rig-id>/``
so several rigs can share one zenoh network.

What travels on each key, and who may send it, is declared once in
:mod:`protocol.rig_description` (``docs/design.md`` shows it as a table);
:class:`Keys` spells the keys out for code, and a test checks that every
key here is a declared channel and every declared channel has its key here.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

_RIG_ID = re.compile(r"[A-Za-z0-9_-]{1,64}")
SERVICES: tuple[str, ...] = ("plant", "controller", "dsp")
"""The three boards (the rig description declares them with their start order)."""


def validate_rig_id(rig_id: str) -> str:
    """A rig id is one key chunk: letters, digits, ``-`` and ``_`` only."""
    # fullmatch, not match: "$" would also accept a trailing newline.
    if not isinstance(rig_id, str) or not _RIG_ID.fullmatch(rig_id):
        raise ValueError(f"rig id {rig_id!r} must be 1-64 characters of [A-Za-z0-9_-]")
    return rig_id


@dataclass(frozen=True)
class ParamKeys:
    """One board's parameter keys: its table (queryable), the changes by role, the answers, the changes taken."""

    params: str
    param_set: str
    param_set_tool: str
    param_answer: str
    param_changes: str


@dataclass(frozen=True)
class Keys:
    """All key expressions of one rig."""

    rig_id: str = "default"

    def __post_init__(self) -> None:
        validate_rig_id(self.rig_id)

    @property
    def root(self) -> str:
        return f"ralf/{self.rig_id}"

    @property
    def batch(self) -> str:
        return f"{self.root}/dsp/batch"

    @property
    def flag(self) -> str:
        return f"{self.root}/dsp/flag"

    @property
    def interrupt(self) -> str:
        return f"{self.root}/dsp/interrupt"

    @property
    def dsp_config(self) -> str:
        return f"{self.root}/dsp/config"

    @property
    def dsp_config_ack(self) -> str:
        return f"{self.root}/dsp/config_ack"

    @property
    def tf(self) -> str:
        return f"{self.root}/dsp/tf"

    @property
    def truth(self) -> str:
        return f"{self.root}/plant/truth"

    @property
    def channel_truth(self) -> str:
        return f"{self.root}/plant/channels"

    @property
    def scenario(self) -> str:
        return f"{self.root}/plant/scenario"

    @property
    def plant_events(self) -> str:
        return f"{self.root}/plant/events"

    @property
    def controller_status(self) -> str:
        return f"{self.root}/controller/status"

    @property
    def controller_command(self) -> str:
        return f"{self.root}/controller/command"

    @property
    def controller_test_command(self) -> str:
        return f"{self.root}/controller/test_command"

    @property
    def params(self) -> str:
        return f"{self.root}/controller/params"

    @property
    def param_set(self) -> str:
        return f"{self.root}/controller/param_set"

    @property
    def param_set_tool(self) -> str:
        return f"{self.root}/controller/param_set_tool"

    @property
    def param_answer(self) -> str:
        return f"{self.root}/controller/param_answer"

    @property
    def param_changes(self) -> str:
        return f"{self.root}/controller/param_changes"

    @property
    def plant_params(self) -> str:
        return f"{self.root}/plant/params"

    @property
    def plant_param_set(self) -> str:
        return f"{self.root}/plant/param_set"

    @property
    def plant_param_set_tool(self) -> str:
        return f"{self.root}/plant/param_set_tool"

    @property
    def plant_param_answer(self) -> str:
        return f"{self.root}/plant/param_answer"

    @property
    def plant_param_changes(self) -> str:
        return f"{self.root}/plant/param_changes"

    @property
    def tf_downloads(self) -> str:
        return f"{self.root}/controller/tf"

    def health(self, service: str) -> str:
        return f"{self.root}/health/{service}"

    @property
    def health_all(self) -> str:
        return f"{self.root}/health/*"

    def alive(self, service: str) -> str:
        return f"{self.root}/alive/{service}"

    @property
    def alive_all(self) -> str:
        return f"{self.root}/alive/*"


def param_keys(keys: Keys, board: str) -> ParamKeys:
    """The parameter keys of ``board`` (``controller`` or ``plant``; docs/calibration.md)."""
    if board == "controller":
        return ParamKeys(keys.params, keys.param_set, keys.param_set_tool, keys.param_answer, keys.param_changes)
    if board == "plant":
        return ParamKeys(keys.plant_params, keys.plant_param_set, keys.plant_param_set_tool, keys.plant_param_answer, keys.plant_param_changes)
    raise ValueError(f"no board {board!r} serves parameters (controller, plant)")
