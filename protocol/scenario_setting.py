"""The plant's ``scenario`` setting: a JSON list of :class:`ScenarioCommand`
applied at their simulated times, or a JSON object with sections
``commands`` (that list), ``channel_faults`` (faults on the node's signal
channels, :mod:`protocol.channel_faults`) and ``stimulus`` (profiles on the
plant's inputs, :mod:`protocol.stimulus`). Parsed here, where the settings
validate it at load (a bad list is refused before the plant's node boots on
the bus), and by the plant when it starts."""

from __future__ import annotations

import json
from typing import Any

from protocol.bounded_parse import TooLarge, load_json
from protocol.channel_faults import ChannelFault, FaultSchedule
from protocol.errors import ConfigError
from protocol.messages import ScenarioCommand
from protocol.stimulus import StimulusPlan, fault_size_ranges, parse_stimulus

__all__ = ["SECTIONS", "parse_channel_faults", "parse_scenario", "parse_scenario_stimulus"]

SECTIONS = ("commands", "channel_faults", "stimulus")
"""The sections of a scenario given as a JSON object."""


def parse_scenario(text: str) -> list[ScenarioCommand]:
    """Scenario commands from the ``scenario`` setting (a JSON list, or the object's ``commands``)."""
    items = _section(text, "commands")
    commands = []
    for seq, item in enumerate(items):
        try:
            commands.append(ScenarioCommand.model_validate({"seq": seq, "sim_time_s": 0.0, **item}))
        except Exception as exc:
            raise ConfigError(f"RALF_SCENARIO item {seq}: {_one_line(exc)}") from None
    return commands


def parse_channel_faults(text: str) -> FaultSchedule:
    """The ``channel_faults`` section of the ``scenario`` setting (empty for a plain list)."""
    items = _section(text, "channel_faults")
    faults = []
    for n, item in enumerate(items):
        try:
            faults.append(ChannelFault.model_validate(item))
        except Exception as exc:
            raise ConfigError(f"RALF_SCENARIO channel_faults item {n}: {_one_line(exc)}") from None
    return FaultSchedule(faults=tuple(faults))


def parse_scenario_stimulus(text: str) -> StimulusPlan:
    """The ``stimulus`` section of the ``scenario`` setting: the plant inputs' profiles (:mod:`protocol.stimulus`; empty for a plain list),
    a profile on a channel fault's size checked against the ``channel_faults`` section (:func:`protocol.stimulus.fault_size_ranges`)."""
    where = "RALF_SCENARIO stimulus"
    plan = parse_stimulus(_section(text, "stimulus"), "plant", where=where)
    if any(p.input.startswith("channel_fault.") for p in plan.profiles):
        fault_size_ranges(plan, parse_channel_faults(text).faults, where)
    return plan


def _section(text: str, name: str) -> list[Any]:
    """One section's items: a JSON list is the ``commands`` section alone."""
    if not text.strip():
        return []
    try:
        parsed = load_json(text, "RALF_SCENARIO")
    except json.JSONDecodeError as exc:
        raise ConfigError(f"RALF_SCENARIO is not JSON: {exc}") from None
    except TooLarge as exc:
        raise ConfigError(str(exc)) from None
    if isinstance(parsed, list):
        items: Any = parsed if name == "commands" else []
    elif isinstance(parsed, dict):
        unknown = sorted(set(parsed) - set(SECTIONS))
        if unknown:
            raise ConfigError(f"RALF_SCENARIO has no section {unknown[0]!r}; allowed: {', '.join(SECTIONS)}")
        items = parsed.get(name, [])
    else:
        raise ConfigError("RALF_SCENARIO must be a JSON list of commands or an object with sections " + ", ".join(SECTIONS))
    if not isinstance(items, list):
        raise ConfigError(f"RALF_SCENARIO {name} must be a JSON list")
    for n, item in enumerate(items):
        if not isinstance(item, dict):
            raise ConfigError(f"RALF_SCENARIO {'' if name == 'commands' else name + ' '}item {n} must be a JSON object")
    return list(items)


def _one_line(exc: Exception) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        return "; ".join(_error_text(e) for e in errors())
    return " ".join(str(exc).split())


def _error_text(error: Any) -> str:
    where = ".".join(map(str, error["loc"]))
    message = str(error["msg"]).removeprefix("Value error, ")
    return f"{where}: {message}" if where else message
