"""The first identified pole against the plant's first mode: frequency and damping errors over parts of a run."""

from __future__ import annotations

from typing import Any

import numpy as np

from workbench.rig_record import RunRecord

__all__ = ["ERROR_COLUMNS", "error_cells", "identification_errors"]


def identification_errors(res: RunRecord, apex: np.ndarray, after_s: float) -> dict[str, Any]:
    """First identified pole (``f_id_hz``, ``zeta_id``) against the plant's first mode (frequency and damping),
    over the whole run, at the apex (``apex``, per tick) and away from it, over the samples after ``after_s``
    with an estimate; damping only where the pole is on the first mode (±10 %)."""
    t = res.t_s
    f = np.asarray(res.columns["f_id_hz"], dtype=float)
    z = np.asarray(res.columns["zeta_id"], dtype=float)
    f1 = res.true_mode_hz(t, 0)
    z1 = np.interp(t, np.asarray(res.truth_columns["sim_time_s"]) - res.sample_period_s, np.asarray(res.truth_columns["damping_ratios"])[:, 0])
    late = (t >= after_s) & np.isfinite(f)
    out: dict[str, Any] = {}
    for name, m in (("whole", late), ("apex", late & apex[: t.size]), ("away", late & ~apex[: t.size])):
        rel = np.abs(f[m] - f1[m]) / f1[m]
        on = m & (np.abs(f - f1) <= 0.1 * f1) & np.isfinite(z)
        zr = z[on] / z1[on] - 1.0
        out[name] = {
            "samples": int(m.sum()),
            "median_rel_f_error": float(np.median(rel)) if rel.size else float("nan"),
            "within_5pct": float(np.mean(rel <= 0.05)) if rel.size else float("nan"),
            "on_first_mode": float(on.sum() / max(1, m.sum())),
            "median_zeta": float(np.median(z[on])) if on.any() else float("nan"),
            "true_zeta": float(np.median(z1[on])) if on.any() else float("nan"),
            "median_rel_zeta_error": float(np.median(np.abs(zr))) if zr.size else float("nan"),
            "zeta_within_25pct": float(np.mean(np.abs(zr) <= 0.25)) if zr.size else float("nan"),
        }
    return out


ERROR_COLUMNS = [
    "median |f1 error| whole (%)",
    "at the apex (%)",
    "away (%)",
    "away: within 5 % (% of samples)",
    "away: median ζ",
    "true ζ1",
    "away: ζ within ±25 % (%)",
]
"""The table columns of :func:`error_cells`."""


def error_cells(errors: dict[str, Any]) -> list[float]:
    """One run's :func:`identification_errors` as table cells (:data:`ERROR_COLUMNS`; shares in %)."""
    whole, apex, away = errors["whole"], errors["apex"], errors["away"]
    return [
        100 * whole["median_rel_f_error"],
        100 * apex["median_rel_f_error"],
        100 * away["median_rel_f_error"],
        100 * away["within_5pct"],
        away["median_zeta"],
        away["true_zeta"],
        100 * away["zeta_within_25pct"],
    ]
