"""The data a check's figure is drawn from: curves, allowed bands, limit lines and
the measured point, in panels over one time axis (plain data: no matplotlib)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True, eq=False)
class Trace:
    """A curve of a figure (``style``: a ``line``, a ``step`` curve or ``points``)."""

    t: npt.NDArray[np.float64]
    values: npt.NDArray[np.float64]
    label: str
    style: Literal["line", "step", "points"] = "line"


@dataclass(frozen=True, eq=False)
class Band:
    """The allowed region between ``low`` and ``high`` over the times ``t`` (shaded)."""

    t: npt.NDArray[np.float64]
    low: npt.NDArray[np.float64]
    high: npt.NDArray[np.float64]
    label: str


@dataclass(frozen=True)
class Mark:
    """A marked point (the measured value where it was measured)."""

    t: float
    value: float
    label: str


@dataclass(frozen=True, eq=False)
class Panel:
    """One axes of a figure: curves, allowed bands, limit lines and marked points."""

    ylabel: str
    traces: tuple[Trace, ...] = ()
    bands: tuple[Band, ...] = ()
    hlines: tuple[tuple[float, str], ...] = ()
    vlines: tuple[tuple[float, str], ...] = ()
    """Limits in time (``start + within_s``)."""
    instants: tuple[tuple[float, str], ...] = ()
    """Times the check measured from (a cause), drawn apart from the limits."""
    marks: tuple[Mark, ...] = ()


@dataclass(frozen=True, eq=False)
class FigureData:
    """The data a check's figure draws: panels stacked over one time axis."""

    title: str
    panels: tuple[Panel, ...]
    xlabel: str = "time (s)"
