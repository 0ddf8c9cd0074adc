"""A check's figure from its :class:`~workbench.checks.figure_data.FigureData`: matplotlib's
Agg canvas, no pyplot (no global state: safe in a test session and in threads)."""

from __future__ import annotations

import io

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from workbench.checks.figure_data import FigureData, Panel

COLOURS = {"PASS": "tab:green", "FAIL": "tab:red", "INVALID": "tab:gray"}


def _panel(ax: object, panel: Panel, colour: str) -> None:
    from matplotlib.axes import Axes

    assert isinstance(ax, Axes)
    for band in panel.bands:
        if band.t.size:
            ax.fill_between(band.t, band.low, band.high, color="tab:blue", alpha=0.15, step=None, label=band.label)
    for trace in panel.traces:
        if trace.style == "points":
            ax.plot(trace.t, trace.values, ".", markersize=4, label=trace.label)
        elif trace.style == "step":
            ax.step(trace.t, trace.values, where="post", label=trace.label)
        else:
            ax.plot(trace.t, trace.values, linewidth=1.0, label=trace.label)
    for value, label in panel.hlines:
        if np.isfinite(value):
            ax.axhline(value, color="tab:orange", linestyle="--", linewidth=1.0, label=label)
    for value, label in panel.vlines:
        if np.isfinite(value):
            ax.axvline(value, color="tab:orange", linestyle=":", linewidth=1.2, label=label)
    for value, label in panel.instants:
        if np.isfinite(value):
            ax.axvline(value, color="tab:gray", linestyle="-.", linewidth=1.0, label=label)
    for mark in panel.marks:
        if np.isfinite(mark.t) and np.isfinite(mark.value):
            ax.plot([mark.t], [mark.value], "o", color=colour, markersize=7, markerfacecolor="none", markeredgewidth=2, label=mark.label)
    ax.set_ylabel(panel.ylabel)
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=7, loc="best")


def draw(data: FigureData | None, title: str, level: str) -> Figure:
    """The figure of one check: its signal(s), the limit or band, the measured point; the
    title is the check's line (name, verdict, what it measured), in the verdict's colour."""
    panels = data.panels if data is not None else ()
    fig = Figure(figsize=(7.0, 1.2 + 2.4 * max(1, len(panels))), layout="constrained")
    FigureCanvasAgg(fig)
    colour = COLOURS.get(level, "black")
    if not panels:
        ax = fig.add_subplot()
        ax.text(0.5, 0.5, "no data to draw", ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
    else:
        axes = fig.subplots(len(panels), 1, sharex=True, squeeze=False)[:, 0]
        for ax, panel in zip(axes, panels):
            _panel(ax, panel, colour)
        axes[-1].set_xlabel(data.xlabel if data is not None else "time (s)")
    fig.suptitle(_wrap(title), fontsize=9, color=colour)
    return fig


def _wrap(text: str, width: int = 95) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width)) or text


def png(fig: Figure, dpi: int = 90) -> bytes:
    """A figure as PNG bytes (the HTML report's attachment)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
