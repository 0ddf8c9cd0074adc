"""Grouped bar charts: one bar per series side by side at each category, optionally labelled."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class BarSeries:
    """One series: its bars' ``values`` (one per category), legend ``label``, ``colour`` and,
    if given, the text over each bar (``annotations``, formatted with :attr:`fmt`)."""

    label: str
    colour: str
    values: Sequence[float]
    annotations: Sequence[float] | None = None
    fmt: str = "{:.0f}"


def grouped_bars(ax: Any, categories: Sequence[str], series: Sequence[BarSeries], *, width: float | None = None, fontsize: float = 6) -> None:
    """Draw ``series`` as grouped bars on the matplotlib axes ``ax``, the ``categories`` as tick labels."""
    n = len(series)
    w = 0.8 / n if width is None else width
    x = np.arange(len(categories))
    for j, s in enumerate(series):
        pos = x + (j - (n - 1) / 2) * w
        ax.bar(pos, s.values, w, color=s.colour, label=s.label)
        if s.annotations is not None:
            for p_, v_, a_ in zip(pos, s.values, s.annotations):
                ax.annotate(s.fmt.format(a_), (p_, v_), textcoords="offset points", xytext=(0, 2), ha="center", fontsize=fontsize)
    ax.set_xticks(x, list(categories), fontsize=7)
    ax.grid(True, axis="y", lw=0.3)
