"""The plant's ``scenario`` setting: a JSON list of :class:`ScenarioCommand`
applied at their simulated times. Parsed here, where the settings validate it
at load (a bad list is refused before the plant's node boots on the bus), and
by the plant when it starts."""

from __future__ import annotations

import json

from protocol.bounded_parse import TooLarge, load_json
from protocol.errors import ConfigError
from protocol.messages import ScenarioCommand

__all__ = ["parse_scenario"]


def parse_scenario(text: str) -> list[ScenarioCommand]:
    """Scenario commands from the ``scenario`` setting (a JSON list)."""
    if not text.strip():
        return []
    try:
        items = load_json(text, "RALF_SCENARIO")
    except json.JSONDecodeError as exc:
        raise ConfigError(f"RALF_SCENARIO is not JSON: {exc}") from None
    except TooLarge as exc:
        raise ConfigError(str(exc)) from None
    if not isinstance(items, list):
        raise ConfigError("RALF_SCENARIO must be a JSON list of commands")
    commands = []
    for seq, item in enumerate(items):
        try:
            commands.append(ScenarioCommand.model_validate({"seq": seq, "sim_time_s": 0.0, **item}))
        except Exception as exc:
            raise ConfigError(f"RALF_SCENARIO item {seq}: {_one_line(exc)}") from None
    return commands


def _one_line(exc: Exception) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        return "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errors())
    return " ".join(str(exc).split())
