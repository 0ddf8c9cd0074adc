"""A run's scripted parameter changes (the controller's ``param_schedule`` setting,
docs/calibration.md): each ``{"name": "controller.kp1", "value": 8000, "at_s": 2.0}``
sets the parameter (its physical value, in the parameter table's unit) at the
first tick at or after ``at_s`` of simulated time.

Only the shape is checked here (a known-looking name, finite numbers, a time
not before 0); the board that owns the parameter checks the name, the limits
and its own guards when the run starts (one line, ConfigError)."""

from __future__ import annotations

import json
from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError

from protocol.errors import ConfigError

__all__ = ["ParamStep", "parse_param_schedule", "schedule_json"]

MAX_STEPS = 10_000


class ParamStep(BaseModel):
    """One scripted change."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Annotated[str, Field(min_length=3, max_length=64, pattern=r"^[A-Za-z0-9_]+\.[A-Za-z0-9_]+$")]
    value: Annotated[float, Field(allow_inf_nan=False)]
    at_s: Annotated[float, Field(ge=0.0, le=1e7, allow_inf_nan=False)] = 0.0


_STEPS: TypeAdapter[list[ParamStep]] = TypeAdapter(Annotated[list[ParamStep], Field(max_length=MAX_STEPS)])


def parse_param_schedule(value: str | list[Any] | None) -> tuple[ParamStep, ...]:
    """The steps of a ``param_schedule`` (JSON text or a list), in time order (stable:
    steps at the same time keep their order); raises a one-line :class:`ConfigError`."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return ()
    try:
        data = json.loads(value) if isinstance(value, str) else value
    except json.JSONDecodeError as exc:
        raise ConfigError(f"param_schedule is not JSON: {exc}") from None
    try:
        steps = _STEPS.validate_python(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ConfigError(f"param_schedule: {where}: {first['msg']}" if where else f"param_schedule: {first['msg']}") from None
    return tuple(sorted(steps, key=lambda s: s.at_s))


def schedule_json(steps: list[ParamStep] | tuple[ParamStep, ...]) -> str:
    """The setting's text of ``steps``."""
    return json.dumps([s.model_dump() for s in steps])
