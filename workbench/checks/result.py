"""What a check returns: its verdict, the measured value against the limit, one
line that says so, and the data of its figure.

A result is PASS, FAIL or INVALID. INVALID means the check compared nothing
(an empty or too short signal, a window with no sample, a cause that never
came): it is never a pass.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

from workbench.checks.figure_data import Band, FigureData, Mark, Panel, Trace

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Band", "CheckResult", "FigureData", "Level", "Mark", "Panel", "Trace", "fmt", "invalid", "judged", "tidy"]

Level = Literal["PASS", "FAIL", "INVALID"]


def fmt(x: float) -> str:
    """A measured value or limit as the lines print it (4 significant digits)."""
    if math.isnan(x):
        return "nan"
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.4g}"


def tidy(sentence: str) -> str:
    """One line, single spaces, no space before a closing bracket or comma (a unit left empty)."""
    return re.sub(r"\s+([),;:])", r"\1", " ".join(sentence.split()))


@dataclass(frozen=True, eq=False)
class CheckResult:
    """One check's outcome.

    ``measured`` is the value the check judged (NaN when it compared nothing),
    ``limit`` the value it was held to, both in ``unit``; ``details`` holds the
    other numbers the check found (a lag, a time, a sample count)."""

    name: str
    """The check and its signal(s): ``overshoot_below(phi1)``."""
    level: Level
    measured: float
    limit: float
    unit: str
    sentence: str
    """What :meth:`explain` says: ``overshoot 23.4 % against a limit of 10 %``."""
    data: FigureData | None = None
    details: Mapping[str, float] = field(default_factory=dict)

    @property
    def passed(self) -> bool:
        return self.level == "PASS"

    def explain(self) -> str:
        """One line: what was measured against what limit (``overshoot 23.4 % against a limit of 10 %``)."""
        return self.sentence

    def line(self) -> str:
        """The check's name, verdict and :meth:`explain` in one line (the assertion's message)."""
        return f"{self.name} {self.level}: {self.sentence}"

    def property_value(self) -> str:
        """The JUnit property's value: ``PASS measured=0.0123 limit=0.014 unit=rad``."""
        unit = f" unit={self.unit}" if self.unit else ""
        return f"{self.level} measured={fmt(self.measured)} limit={fmt(self.limit)}{unit}"

    def figure(self) -> Figure:
        """A matplotlib figure (Agg, no pyplot state) of the signal, the limit or band and
        the measured point; a figure saying it compared nothing when there is no data."""
        from workbench.checks.figure import draw

        return draw(self.data, self.line(), self.level)


def invalid(name: str, why: str, limit: float, unit: str, data: FigureData | None = None) -> CheckResult:
    """A result that compared nothing (``why`` says what was missing)."""
    return CheckResult(name, "INVALID", math.nan, limit, unit, tidy(f"compared nothing: {why}"), data)


def judged(
    name: str, ok: bool, measured: float, limit: float, unit: str, sentence: str, data: FigureData | None, details: Mapping[str, float] | None = None
) -> CheckResult:
    """A result that compared something: PASS when ``ok``, else FAIL."""
    return CheckResult(name, "PASS" if ok else "FAIL", float(measured), float(limit), unit, tidy(sentence), data, dict(details or {}))
