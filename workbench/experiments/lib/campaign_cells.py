"""A campaign's runs as cells: each configuration's cost in % of a baseline configuration, and what moves it.

A campaign (``workbench.campaign``) gives one row per run: its point's label
(``point``), the values of its grid axes and its seed, and its metrics. Here a
*cell* is one point label at one combination of two grid axes; its entries
are its seeds. Every run is put in % of the baseline point's run of the same
axes and seed (the same noise draws: common random numbers), then averaged
over the seeds; the spread between seeds is the campaign's resolution.
A *main effect* of an axis is the range (max − min) of a metric's mean over
the axis's values, the other axes averaged.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from workbench.experiments.report import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Cells", "cell", "cell_mean", "cell_heatmaps", "main_effects", "pct_of_baseline_cells", "seed_spread"]

Cells = dict[str, dict[str, dict[str, dict[str, float]]]]
"""``cells[label][row value][column value]``: the cell's metrics (mean over seeds), ``<metric>_pct``, ``<metric>_pct_seed_spread``, ``seeds``."""


def key(value: Any) -> str:
    """An axis value as a cell key (``12`` -> ``"12"``, ``1.0`` -> ``"1"``)."""
    return f"{value:g}"


def _f(value: Any) -> float:
    """A table cell as a float (missing -> NaN; the journal keeps non-finite numbers as null or text)."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return float("nan")


def _pct(v: float, base: float) -> float:
    return 100.0 * v / base if base and math.isfinite(base) else float("nan")


def pct_of_baseline_cells(
    rows: Sequence[Mapping[str, Any]], axes: tuple[str, str], seed: str, baseline: str, costs: Sequence[str], also: Sequence[str] = ()
) -> Cells:
    """Per (point label, value of ``axes[0]``, value of ``axes[1]``), over the ``ok`` rows: each of ``costs`` and its %
    of the ``baseline`` point's run of the same axes and ``seed`` (rows without that baseline are left out) and each
    of ``also``, as the mean over the seeds; with ``seeds`` and each ``_pct``'s range between the seeds (NaN with one)."""
    ok = [r for r in rows if r.get("status") == "ok"]
    base = {(r[axes[0]], r[axes[1]], r[seed]): r for r in ok if r["point"] == baseline}
    entries: dict[tuple[str, Any, Any], list[dict[str, float]]] = defaultdict(list)
    for r in ok:
        b = base.get((r[axes[0]], r[axes[1]], r[seed]))
        if b is None:
            continue
        entry: dict[str, float] = {}
        for k in costs:
            entry[k] = _f(r.get(k))
            entry[f"{k}_pct"] = _pct(_f(r.get(k)), _f(b.get(k)))
        entry.update({k: _f(r.get(k)) for k in also})
        entries[(r["point"], r[axes[0]], r[axes[1]])].append(entry)
    out: Cells = {}
    for (label, a, b), es in entries.items():
        mean = {k: float(np.nanmean([e[k] for e in es])) if any(math.isfinite(e[k]) for e in es) else float("nan") for k in es[0]}
        mean["seeds"] = len(es)
        for k in [k for k in es[0] if k.endswith("_pct")]:
            vals = [e[k] for e in es if math.isfinite(e[k])]
            mean[f"{k}_seed_spread"] = float(max(vals) - min(vals)) if len(vals) > 1 else float("nan")
        out.setdefault(label, {}).setdefault(key(a), {})[key(b)] = mean
    return out


def cell(cells: Cells, label: str, a: Any, b: Any) -> dict[str, float] | None:
    """The cell of ``label`` at axis values ``a``, ``b`` (None if the campaign has none)."""
    return cells.get(label, {}).get(key(a), {}).get(key(b))


def cell_mean(cells: Cells, labels: Sequence[str], a_values: Sequence[Any], b_values: Sequence[Any], metric: str) -> float:
    """Mean of ``metric`` over the cells of ``labels`` at every pair of the axes' values (NaN: none)."""
    vals = [c[metric] for lab in labels for a in a_values for b in b_values if (c := cell(cells, lab, a, b)) is not None]
    return float(np.nanmean(vals)) if vals else float("nan")


def seed_spread(cells: Cells, metric: str) -> float:
    """Median over every cell of the range of ``metric`` between its seeds (NaN with one seed)."""
    k = f"{metric}_seed_spread"
    vals = [c[k] for by_a in cells.values() for by_b in by_a.values() for c in by_b.values() if k in c]
    vals = [v for v in vals if math.isfinite(v)]
    return float(np.median(vals)) if vals else float("nan")


def main_effects(
    cells: Cells, labels: Sequence[str], a_values: Sequence[Any], b_values: Sequence[Any], label_axis: Callable[[str], str], metric: str
) -> tuple[float, float, float]:
    """Main effects on ``metric`` over the cells of ``labels``: of axis a, of axis b, and of the label axis (the cells
    grouped by ``label_axis(label)``), each the range of the group means."""

    def rng(groups: dict[Any, list[float]]) -> float:
        means = [float(np.nanmean(v)) for v in groups.values() if v]
        return float(max(means) - min(means)) if len(means) > 1 else 0.0

    by: tuple[dict[Any, list[float]], ...] = (defaultdict(list), defaultdict(list), defaultdict(list))
    for lab in labels:
        for a in a_values:
            for b in b_values:
                c = cell(cells, lab, a, b)
                if c is not None:
                    for group, value in zip(by, (a, b, label_axis(lab))):
                        group[value].append(c[metric])
    return rng(by[0]), rng(by[1]), rng(by[2])


def cell_heatmaps(
    cells: Cells,
    labels: Sequence[str],
    a_values: Sequence[Any],
    b_values: Sequence[Any],
    metric: str,
    title: Callable[[str], str],
    axis_names: tuple[str, str],
    colour_label: str,
) -> Figure:
    """One heatmap per label (rows) and link (columns; ``metric.format(link)``): ``a_values`` up, ``b_values`` across, in % (20-100)."""
    fig = new_figure(7.5, 1.9 * len(labels) + 0.6)
    axes = np.atleast_2d(fig.subplots(len(labels), 2, squeeze=False))
    im = None
    for r, lab in enumerate(labels):
        for j in (1, 2):
            ax = axes[r][j - 1]
            grid = np.full((len(a_values), len(b_values)), np.nan)
            for ai, a in enumerate(a_values):
                for bi, b in enumerate(b_values):
                    c = cell(cells, lab, a, b)
                    if c is not None:
                        grid[ai, bi] = c[metric.format(j)]
            im = ax.imshow(grid, origin="lower", cmap="viridis_r", vmin=20, vmax=100, aspect="auto")
            for ai in range(len(a_values)):
                for bi in range(len(b_values)):
                    if np.isfinite(grid[ai, bi]):
                        ax.text(bi, ai, f"{grid[ai, bi]:.0f}", ha="center", va="center", fontsize=7, color="w" if grid[ai, bi] > 60 else "k")
            ax.set_xticks(range(len(b_values)), [f"×{b:g}" for b in b_values], fontsize=7)
            ax.set_yticks(range(len(a_values)), [str(a) for a in a_values], fontsize=7)
            ax.set_title(f"{title(lab)}, link {j}", fontsize=7)
            if j == 1:
                ax.set_ylabel(axis_names[0], fontsize=7)
            if r == len(labels) - 1:
                ax.set_xlabel(axis_names[1], fontsize=7)
    if im is not None:
        fig.colorbar(im, ax=axes, shrink=0.6, label=colour_label)
    return fig
