"""The §4.2.1 costs of a run against a baseline run: what an OATF configuration buys.

The cost of a run is the RMS (standard deviation) of the deflection velocity
(10-sample linear regression) and acceleration (40-sample quadratic
regression) per link (``controller.metrics``), over every sample or a masked
stretch (:func:`workbench.experiments.analysis.costs_over`: derivatives from
the whole run, only the samples counted change). An OATF configuration is
judged by its costs in % of the unfiltered run's over the same samples
(thesis Table 4-1: % of configuration (a)).
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np
import numpy.typing as npt

from workbench.experiments.analysis import costs_over
from workbench.rig_record import RunRecord


class RelativeCosts(TypedDict):
    """A run's costs, absolute and in % of a baseline's, per link (the keys :func:`~workbench.experiments.report.cost_cells` reads)."""

    velocity_rms_in_s: list[float]
    acceleration_rms_in_s2: list[float]
    velocity_pct: list[float]
    acceleration_pct: list[float]


def run_costs(record: RunRecord, mask: npt.ArrayLike | None = None) -> dict[str, list[float]]:
    """The §4.2.1 costs of ``record`` over ``mask`` (default: every sample; a longer mask is cut to the run)."""
    n = record.deflections.shape[0]
    m = np.ones(n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)[:n]
    return costs_over(record.deflections, m, record.sample_period_s)


def relative_costs(costs: dict[str, list[float]], baseline: dict[str, list[float]]) -> RelativeCosts:
    """``costs`` (from :func:`run_costs`) absolute and in % of ``baseline``'s, per link."""
    return {
        "velocity_rms_in_s": costs["velocity_rms"],
        "acceleration_rms_in_s2": costs["acceleration_rms"],
        "velocity_pct": [100 * a / b for a, b in zip(costs["velocity_rms"], baseline["velocity_rms"])],
        "acceleration_pct": [100 * a / b for a, b in zip(costs["acceleration_rms"], baseline["acceleration_rms"])],
    }


def costs_against(record: RunRecord, baseline: RunRecord | dict[str, list[float]], mask: npt.ArrayLike | None = None) -> RelativeCosts:
    """The costs of ``record`` over ``mask`` in % of the ``baseline`` run's over the same samples
    (or of costs already computed: :func:`run_costs`)."""
    base = run_costs(baseline, mask) if isinstance(baseline, RunRecord) else baseline
    return relative_costs(run_costs(record, mask), base)
