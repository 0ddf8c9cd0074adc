"""A signal for the checks: sample times, values, a name and a unit.

The checks (:mod:`workbench.checks`) take signals, never a run record; a
record's signals come from :func:`workbench.checks.record_signals.signal`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

SignalKind = Literal["series", "events", "count", "run_max"]
"""What the samples are: a sampled ``series``; ``events`` (one sample per event, value 1 at
its time); a ``count`` (one sample: a total at the run's end); a ``run_max`` (one sample:
the longest run in a row the counter's owner saw)."""


@dataclass(frozen=True, eq=False)
class Signal:
    """Samples ``values`` at times ``t`` (s), named and in ``unit``."""

    t: npt.NDArray[np.float64]
    values: npt.NDArray[np.float64]
    name: str
    unit: str = ""
    kind: SignalKind = "series"
    source: str = field(default="", compare=False)
    """Where the samples came from (a column, truth field, ...): shown in a check's figure."""

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float).reshape(-1)
        v = np.asarray(self.values, dtype=float).reshape(-1)
        if t.shape != v.shape:
            raise ValueError(f"signal {self.name!r}: {t.size} times for {v.size} values")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "values", v)

    def __len__(self) -> int:
        return int(self.t.size)

    def since(self, t_s: float | None) -> Signal:
        """The samples at ``t_s`` and after (all of them for None)."""
        if t_s is None:
            return self
        keep = self.t >= t_s
        return Signal(self.t[keep], self.values[keep], self.name, self.unit, self.kind, self.source)

    def derive(self, values: npt.ArrayLike, name: str, unit: str | None = None) -> Signal:
        """Another signal on the same times (``phi1 - phi_ref1``, a condition as 0/1, ...)."""
        return Signal(self.t, np.asarray(values, dtype=float), name, self.unit if unit is None else unit, "series", self.source)

    def where(self, condition: Callable[[npt.NDArray[np.float64]], npt.ArrayLike], name: str) -> Signal:
        """1 where ``condition(values)`` holds, else 0 (a detection for :func:`~workbench.checks.detected_within`)."""
        return self.derive(np.asarray(condition(self.values), dtype=bool).astype(float), name, "")

    @classmethod
    def of(cls, t: npt.ArrayLike, values: npt.ArrayLike, name: str, unit: str = "") -> Signal:
        """A series from arrays (a test's own reference, a simulated response)."""
        return cls(np.asarray(t, dtype=float), np.asarray(values, dtype=float), name, unit)
