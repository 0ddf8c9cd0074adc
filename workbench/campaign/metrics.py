"""The metrics row of one run, from the controller's record and the plant's ground truth.

Costs are the thesis's §4.2.1 figures of merit (``controller.metrics``, as
the battery computes them through :func:`workbench.experiments.analysis.costs_over`):
the RMS (standard deviation over the run) of the deflection velocity
(10-sample linear regression) and acceleration (40-sample quadratic
regression) per link, of the deflections the controller *measured*
(``velocity_rms_1`` ...: what the rig's own sensors report, sensor noise
included) and, when the plant logged its truth at the sample rate, of the
*true* deflections (``true_velocity_rms_1`` ...: the arm's actual vibration).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from workbench.experiments.analysis import costs_over

__all__ = ["COUNTERS", "detection_metrics", "run_metrics"]

COUNTERS = (
    "batches_sent",
    "interrupts",
    "interrupts_lost",
    "deadline_misses",
    "samples_dropped",
    "oatf_updates",
    "stale_episodes",
    "overruns",
    "sync_retries",
    "syncs_sent",
    "tpdos",
)
"""Controller counters copied into the row."""


def _costs(prefix: str, deflections: np.ndarray, period_s: float) -> dict[str, float]:
    c = costs_over(deflections, np.ones(deflections.shape[0], dtype=bool), period_s)
    return {
        f"{prefix}velocity_rms_1": float(c["velocity_rms"][0]),
        f"{prefix}velocity_rms_2": float(c["velocity_rms"][1]),
        f"{prefix}acceleration_rms_1": float(c["acceleration_rms"][0]),
        f"{prefix}acceleration_rms_2": float(c["acceleration_rms"][1]),
    }


def run_metrics(
    columns: Mapping[str, np.ndarray],
    truth: Mapping[str, np.ndarray] | None,
    counters: Mapping[str, int],
    *,
    sample_period_s: float,
    wall_s: float,
) -> dict[str, Any]:
    """Every number of the row (flat: names to floats and ints)."""
    t = np.asarray(columns["t_s"], dtype=float)
    defl = np.column_stack([columns["defl1_in"], columns["defl2_in"]]).astype(float)
    row: dict[str, Any] = {
        "ticks": int(t.size),
        "sim_time_s": float(t.size * sample_period_s),
        "wall_s": float(wall_s),
        "realtime_factor": float(t.size * sample_period_s / wall_s) if wall_s > 0 else float("nan"),
    }
    row.update({k: int(counters.get(k, 0)) for k in COUNTERS})
    row.update(_costs("", defl, sample_period_s))
    err = np.column_stack([columns["phi_ref1"], columns["phi_ref2"]]) - np.column_stack([columns["phi1"], columns["phi2"]])
    row["tracking_rms_1_rad"], row["tracking_rms_2_rad"] = (float(x) for x in np.sqrt(np.mean(err.astype(float) ** 2, axis=0)))
    row["max_abs_u_v"] = float(np.max(np.abs(np.column_stack([columns["u1_v"], columns["u2_v"]]))))
    f_oatf = np.asarray(columns["oatf_hz"], dtype=float)
    changed = np.flatnonzero(np.abs(np.diff(f_oatf)) > 1e-12)
    row["oatf_design_changes"] = int(changed.size)
    row["oatf_first_change_s"] = float(t[changed[0] + 1]) if changed.size else float("nan")
    row["oatf_median_hz"] = float(np.median(f_oatf))
    f_id = np.asarray(columns["f_id_hz"], dtype=float)
    finite = np.flatnonzero(np.isfinite(f_id))
    row["id_first_estimate_s"] = float(t[finite[0]]) if finite.size else float("nan")
    row["id_last_hz"] = float(f_id[finite[-1]]) if finite.size else float("nan")
    if truth is not None and np.asarray(truth.get("sim_time_s", [])).size > 1:
        ts = np.asarray(truth["sim_time_s"], dtype=float)
        f1 = np.asarray(truth["modal_frequencies_hz"], dtype=float)[:, 0]
        # controller tick k (t = k Ts) sees the plant at (k + 1) Ts
        true1 = np.interp(t + sample_period_s, ts, f1)
        row["true_f1_mean_hz"] = float(np.mean(true1))
        rel = np.abs(f_oatf - true1) / true1
        row["oatf_median_rel_error"] = float(np.median(rel))
        row["oatf_time_within_10pct"] = float(np.mean(rel <= 0.10))
        if "valves_held" in truth:
            row["valves_held_samples"] = int(np.count_nonzero(np.asarray(truth["valves_held"])))
        truth_period = float(np.median(np.diff(ts)))
        if abs(truth_period - sample_period_s) <= 1e-6 * sample_period_s:
            row.update(_costs("true_", np.asarray(truth["deflections_in"], dtype=float), sample_period_s))
    return row


def detection_metrics(events: list[tuple[int, str, str]], monitors: tuple[str, ...], sample_period_s: float) -> dict[str, float]:
    """When each input monitor first fired (``<monitor>_first_s``: simulated time of the
    sample whose check fired, tick ``k`` sampling at ``(k + 1) Ts``; NaN: never) and how many
    times (``<monitor>_episodes``), for a run whose ``input_monitors`` are on."""
    row: dict[str, float] = {}
    for name in monitors:
        ticks = [tick for tick, monitor, _ in events if monitor == name]
        row[f"{name}_first_s"] = (ticks[0] + 1) * sample_period_s if ticks else float("nan")
        row[f"{name}_episodes"] = len(ticks)
    return row
