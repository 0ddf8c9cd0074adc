"""RMS deflection costs of filter designs over noise draws, in % of the unfiltered run of the same draw.

Runs are identified by ``(group, draw, design)`` (design ``None``: the
unfiltered run of that group and draw). Costs are the thesis's §4.2.1 figures
of merit (``controller.metrics.rms_costs``: RMS deflection velocity from a
10-sample slope, acceleration from a 40-sample quadratic regression), each run
also in % of its own unfiltered run (``percent_of_baseline``), then mean and
standard deviation over the draws of a group and design.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.metrics import percent_of_baseline, rms_costs
from workbench.experiments.report import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["RunKey", "cost_bar_chart", "design_costs", "design_label", "design_traces", "pct_of_unfiltered"]

RunKey = tuple[int, int, float | None]
"""``(group, draw, design Hz or None)``."""


def design_label(f: float | None) -> str:
    return "unfiltered" if f is None else f"OATF {f:g} Hz"


def design_costs(
    runs: Sequence[RunKey],
    designs: Sequence[float | None],
    group: int,
    deflections: np.ndarray,
    setpoints: np.ndarray,
    joints: np.ndarray,
    valves: np.ndarray,
    ts: float,
) -> dict[str, dict[str, Any]]:
    """Per design label of ``group``: its costs over its runs (``deflections``, ``setpoints``, ``joints``,
    ``valves`` are ``(runs, n, 2)``); a design with no run is left out."""
    base = {d: i for i, (g, d, f) in enumerate(runs) if g == group and f is None}
    costs = {i: rms_costs(deflections[i], ts) for i, (g, _, _) in enumerate(runs) if g == group}
    out: dict[str, dict[str, Any]] = {}
    for f in designs:
        idx = [i for i, (gg, _, ff) in enumerate(runs) if gg == group and ff == f]
        if not idx:
            continue
        vel = np.array([costs[i].velocity_rms for i in idx])
        acc = np.array([costs[i].acceleration_rms for i in idx])
        pct = [percent_of_baseline(costs[i], costs[base[runs[i][1]]]) for i in idx]
        pct_v = np.array([p.velocity_rms for p in pct])
        pct_a = np.array([p.acceleration_rms for p in pct])
        err = np.array([np.sqrt(np.mean((setpoints[i] - joints[i]) ** 2, axis=0)) for i in idx])
        out[design_label(f)] = {
            "design_hz": f,
            "runs": len(idx),
            "velocity_rms_in_s": vel.mean(0).tolist(),
            "velocity_rms_in_s_std": vel.std(0).tolist(),
            "acceleration_rms_in_s2": acc.mean(0).tolist(),
            "acceleration_rms_in_s2_std": acc.std(0).tolist(),
            "velocity_pct_of_unfiltered": pct_v.mean(0).tolist(),
            "velocity_pct_std": pct_v.std(0).tolist(),
            "acceleration_pct_of_unfiltered": pct_a.mean(0).tolist(),
            "acceleration_pct_std": pct_a.std(0).tolist(),
            "tracking_error_rms_rad": err.mean(0).tolist(),
            "max_abs_valve_v": float(np.max(np.abs(valves[idx]))),
            "max_abs_deflection_in": np.max(np.abs(deflections[idx]), axis=(0, 1)).tolist(),
        }
    return out


PctOfUnfiltered = Callable[[int, float | None, int], float]
"""``(group, design Hz or None, link) -> %`` of the same group's unfiltered run."""


def pct_of_unfiltered(table: Mapping[str, Any], quantity: str) -> PctOfUnfiltered:
    """``table["group<g>"]["designs"][label]``'s ``quantity`` (``velocity`` or ``acceleration``) in % of unfiltered, as a function."""

    def get(gn: int, f: float | None, link: int) -> float:
        return float(table[f"group{gn}"]["designs"][design_label(f)][f"{quantity}_pct_of_unfiltered"][link])

    return get


def cost_bar_chart(table: Mapping[str, Any], groups: Sequence[int], designs: Sequence[float | None]) -> Figure:
    """Bars of RMS deflection velocity and acceleration per group and design (mean ± std over draws), labelled with % of unfiltered."""
    fig = new_figure(11.0, 7.0)
    axes = fig.subplots(2, 2)
    colours = ("0.45", "tab:green", "tab:orange", "tab:blue")
    width = 0.2
    x = np.arange(len(groups))
    for (row, quantity, unit), ax_row in zip((("velocity", "velocity_rms_in_s", "in/s"), ("acceleration", "acceleration_rms_in_s2", "in/s²")), axes):
        for link, ax in enumerate(ax_row):
            for j, (f, col) in enumerate(zip(designs, colours)):
                ds = [table[f"group{g}"]["designs"][design_label(f)] for g in groups]
                vals = [d[quantity][link] if "runs" in d else 0.0 for d in ds]
                errs = [d[quantity + "_std"][link] if "runs" in d else 0.0 for d in ds]
                pcts = [d[f"{row}_pct_of_unfiltered"][link] if "runs" in d else float("nan") for d in ds]
                pos = x + (j - (len(designs) - 1) / 2) * width
                ax.bar(pos, vals, width, yerr=errs, color=col, label=design_label(f), capsize=2)
                if f is not None:
                    for p_, v_, pc in zip(pos, vals, pcts):
                        ax.annotate(f"{pc:.0f}", (p_, v_), textcoords="offset points", xytext=(0, 2), ha="center", fontsize=6)
            ax.set_xticks(x, [f"group {g}" for g in groups])
            ax.set_ylabel(f"RMS deflection {row} ({unit})")
            ax.set_title(f"link {link + 1}", fontsize=9)
            ax.grid(True, axis="y", lw=0.3)
    axes[0][0].legend(fontsize=7)
    return fig


def design_traces(
    t: np.ndarray, setpoints: np.ndarray, deflections: np.ndarray, runs: Sequence[RunKey], *, group: int, window_s: tuple[float, float]
) -> Figure:
    """Joint 2's set-point and link 2's deflection of every run of ``group`` (one line per design) over ``window_s``."""
    fig = new_figure(10.0, 6.0)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    lo, hi = window_s[0], min(window_s[1], float(t[-1]))
    m = (t >= lo) & (t <= hi)
    for i in (i for i, (g, _, _) in enumerate(runs) if g == group):
        ax1.plot(t[m], setpoints[i, m, 1], lw=1.0, label=design_label(runs[i][2]))
        ax2.plot(t[m], deflections[i, m, 1], lw=1.0, label=design_label(runs[i][2]))
    ax1.set_ylabel("φ2 set-point (rad)")
    ax1.set_title(f"group {group}, {lo:g}–{hi:g} s (the first corners of the loop)", fontsize=9)
    ax2.set_ylabel("link-2 deflection (in)")
    ax2.set_xlabel("time (s)")
    ax1.legend(fontsize=7, ncol=4)
    for ax in (ax1, ax2):
        ax.grid(True, lw=0.3)
    return fig
