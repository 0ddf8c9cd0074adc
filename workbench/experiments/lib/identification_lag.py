"""How far an identified first mode lags the true one along a run (thesis §4.2.2, §5: 1 to 4 s).

The identified pole jumps now and then to other peaks for a second or two,
and the true first mode ripples faster than an identifier's window can follow;
so the identified pole is taken as a centred ±1 s running median
(:func:`~workbench.experiments.analysis.centred_median`) and the truth as a
moving average. Two measures (:func:`identification_lag`): the lag at each big
change of the smoothed truth (*transitions*,
:func:`~workbench.experiments.analysis.transition_lags`) and the one shift that
best aligns the two over the whole run (*alignment*,
:func:`~workbench.experiments.analysis.alignment_lag`). :func:`lag_figure`
draws both.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from workbench.experiments.analysis import IdentificationLag, alignment_lag, centred_median, moving_average, transition_lags
from workbench.experiments.report import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["LagTrack", "identification_lag", "lag_figure"]


@dataclass(frozen=True)
class LagTrack:
    """:func:`identification_lag`: the smoothed tracks it compared and what it measured."""

    t_first: float
    """The first tick with an identified pole (s)."""
    f_smooth: np.ndarray
    """The true first mode, moving-averaged, at the truth's times."""
    grid: np.ndarray
    """The truth's times from ``t_first + 2`` s on, where the tracks are compared."""
    m_grid: np.ndarray
    """The identified pole's running median on ``grid``."""
    lag: IdentificationLag
    """Alignment, transitions and their median, and the largest lag searched."""


def identification_lag(
    t: np.ndarray, f_id: np.ndarray, truth_t: np.ndarray, truth_f1: np.ndarray, max_lag_s: float, smooth_s: float, transition_hz: float
) -> LagTrack:
    """The identified first pole ``f_id`` (at the controller's ticks ``t``; NaN before an estimate) against the
    true first mode ``truth_f1`` (at ``truth_t``, on the controller's clock): the truth averaged over ``smooth_s``,
    the pole's ±1 s running median, the transitions (extrema of the smoothed truth ≥ ``transition_hz`` apart) and
    the whole-run alignment, each searched up to ``max_lag_s``, from 2 s after the first estimate on."""
    first = np.flatnonzero(np.isfinite(f_id))
    if not first.size:
        raise RuntimeError("the identifier never reported a pole")
    t_first = float(t[int(first[0])])
    tm, m = centred_median(t, f_id, 1.0)  # running median: drops the estimate's short jumps to other peaks
    truth_rate = 1.0 / float(np.median(np.diff(truth_t)))
    f_smooth = moving_average(truth_f1, int(round(smooth_s * truth_rate)))
    grid = truth_t[(truth_t >= t_first + 2.0) & (truth_t <= t[-1])]
    m_grid = np.interp(grid, tm, m)
    align = alignment_lag(grid, m_grid, np.interp(grid, truth_t, f_smooth), max_lag_s)
    trans = transition_lags(truth_t, f_smooth, tm, m, t_first + 2.0, transition_hz, max_lag_s)
    trans_lags = np.array([x["lag_s"] for x in trans if math.isfinite(x["lag_s"])])
    lag: IdentificationLag = {
        "alignment": align,
        "transitions": trans,
        "median_transition_lag_s": float(np.median(trans_lags)) if trans_lags.size else float("nan"),
        "max_lag_searched_s": max_lag_s,
    }
    return LagTrack(t_first, f_smooth, grid, m_grid, lag)


def lag_figure(track: LagTrack, truth_t: np.ndarray, f_true: np.ndarray, smooth_s: float) -> Figure:
    """Left: the identified pole's running median, the true first mode, its average and the average shifted by
    the alignment lag, with each transition's crossings. Right: the median error against the shift."""
    fig = new_figure(11.0, 3.8)
    ax1, ax2 = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2.2, 1]})
    lag = track.lag
    al = lag["alignment"]
    ax1.plot(truth_t, f_true, color="0.6", lw=0.8, label="true mode 1")
    ax1.plot(truth_t, track.f_smooth, color="k", lw=1.2, label=f"true, {smooth_s:g}-s average")
    ax1.plot(truth_t + al["lag_s"], track.f_smooth, color="k", lw=0.8, ls=":", label=f"the same, shifted {al['lag_s']:.2f} s")
    ax1.plot(track.grid, track.m_grid, color="tab:blue", lw=1.0, label="identified pole 1 (running median)")
    for x in lag["transitions"]:
        ax1.plot([x["true_crossing_s"]], [x["level_hz"]], "k>" if x["direction"] == "up" else "kv", ms=5)
        if math.isfinite(x["lag_s"]):
            ax1.plot([x["true_crossing_s"] + x["lag_s"]], [x["level_hz"]], "o", color="tab:blue", ms=5, mfc="none")
    lo, hi = float(np.nanmin(f_true)), float(np.nanmax(f_true))
    ax1.set_ylim(lo - 0.6, hi + 0.6)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("frequency (Hz)")
    ax1.legend(fontsize=7, loc="lower right")
    ax1.grid(True, lw=0.3)
    ax2.plot(np.asarray(al["lags_s"]), al["median_abs_error_hz"], color="tab:blue")
    ax2.axvline(al["lag_s"], color="tab:blue", ls=":")
    ax2.set_xlabel("shift τ (s)")
    ax2.set_ylabel("median |m(t) − f_true(t − τ)| (Hz)")
    ax2.grid(True, lw=0.3)
    return fig
