"""Figures of the delays after discontinuous changes (:mod:`.identification_delay`): the tracks per run and the
median delays per setting."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from workbench.experiments.report import new_figure
from workbench.hil import RunRecord

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["delay_bars_figure", "tracks_figure"]


def tracks_figure(runs: Sequence[RunRecord], delays: Sequence[Mapping[str, Any]], labels: Sequence[str], events: Sequence[float], tolerance: float) -> Figure:
    """Per run: the identified first pole (dots), its running median (red, ``delays["median_series"]``), the true
    first mode (black) with its ``tolerance`` band, the events (dotted); titled with each event's delays."""
    fig = new_figure(11.0, 2.1 * len(runs) + 0.6)
    axes = np.atleast_1d(fig.subplots(len(runs), 1, sharex=True))
    for ax, r, d, label in zip(axes, runs, delays, labels):
        t = r.t_s
        true1 = r.true_mode_hz(t, 0)
        ax.fill_between(t, true1 * (1 - tolerance), true1 * (1 + tolerance), color="0.85", lw=0)
        ax.plot(t, true1, color="k", lw=1.0)
        ax.plot(t[::10], np.asarray(r.columns["f_id_hz"])[::10], ".", ms=1.5, color="tab:blue")
        ax.plot(d["median_series"]["t_s"], d["median_series"]["f_hz"], color="tab:red", lw=1.0)
        for e in events:
            ax.axvline(e, color="k", ls=":", lw=0.8)
        ax.set_ylim(true1.min() * 0.85, true1.max() * 1.15)
        ax.set_ylabel("Hz")
        ax.set_title(
            f"{label}: delay to 2 % "
            + ", ".join(f"{e['settle_2pct_s']:.1f}" for e in d["events"])
            + " s; to 50 % "
            + ", ".join(f"{e['delay_50pct_s']:.1f}" for e in d["events"])
            + " s",
            fontsize=8,
        )
        ax.grid(True, lw=0.3)
    axes[-1].set_xlabel("time (s)")
    return fig


def delay_bars_figure(rows: Mapping[str, Mapping[str, Any]], tick_labels: Sequence[str], n_events: int, tolerance: float) -> Figure:
    """Per setting (``rows``, in order, labelled ``tick_labels``): the median delays to 2 % and to 50 % (∞ marked,
    settled events counted) and the median error at the end against the ``tolerance``."""
    fig = new_figure(10.0, 3.8)
    ax1, ax2 = fig.subplots(1, 2)
    keys = list(rows)
    x = np.arange(len(keys))
    d2 = [rows[k]["median_settle_2pct_s"] for k in keys]
    d5 = [rows[k]["median_delay_50pct_s"] for k in keys]
    ax1.bar(x - 0.2, [v if math.isfinite(v) else np.nan for v in d2], 0.4, label="to 2 % (median)", color="tab:blue")
    ax1.bar(x + 0.2, [v if math.isfinite(v) else np.nan for v in d5], 0.4, label="to 50 % (median)", color="tab:orange")
    for i, k in enumerate(keys):
        if not math.isfinite(d2[i]):
            ax1.annotate("∞", (i - 0.2, 0), ha="center", va="bottom")
        ax1.annotate(f"{rows[k]['settled_events']}/{n_events}", (i - 0.2, 0), xytext=(0, -22), textcoords="offset points", ha="center", fontsize=6)
    ax1.set_xticks(x, list(tick_labels), fontsize=7)
    ax1.set_ylabel("delay after the event (s)")
    ax1.legend(fontsize=7)
    ax1.grid(True, axis="y", lw=0.3)
    ax2.bar(x, [100 * rows[k]["median_rel_error_end"] for k in keys], 0.6, color="tab:green")
    ax2.axhline(100 * tolerance, color="k", ls=":", lw=0.8)
    ax2.set_xticks(x, list(tick_labels), fontsize=7)
    ax2.set_ylabel("median |error| at the end (%)")
    ax2.grid(True, axis="y", lw=0.3)
    return fig
