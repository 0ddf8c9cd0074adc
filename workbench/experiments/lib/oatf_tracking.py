"""How an adaptive OATF's design frequency followed the plant's true first mode.

The adaptive OATF (thesis §3.3) redesigns on each confident identified pole;
the controller's record holds its design frequency per tick (``oatf_hz``) and
the plant's truth the first modal frequency. :func:`design_changes` is the
redesigns as a 0/1 signal (for :func:`workbench.checks.detected_within`),
:func:`design_against_truth` the numbers a report keeps.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from workbench.checks.signal import Signal
from workbench.rig_record import RunRecord

CHANGE_HZ = 1e-12
"""A design frequency that moved by more than this between ticks was redesigned (Hz)."""


def _design(record: RunRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    f = np.asarray(record.columns["oatf_hz"], dtype=float)
    return f, np.flatnonzero(np.abs(np.diff(f)) > CHANGE_HZ), record.true_mode_hz(record.t_s, 0)


def design_changes(record: RunRecord) -> Signal:
    """1 at each tick whose OATF design frequency differs from the tick before, else 0."""
    f, changed, _ = _design(record)
    flags = np.zeros(f.size)
    flags[changed + 1] = 1.0
    return Signal.of(record.t_s, flags, "OATF design changed")


def design_against_truth(record: RunRecord) -> dict[str, Any]:
    """When the OATF design first moved, how often, its range, and its relative distance to the true first mode
    (median over the run and after the first change, share of ticks within 10 %)."""
    t = record.t_s
    f, changed, true1 = _design(record)
    first = float(t[changed[0] + 1]) if changed.size else float("nan")
    rel = np.abs(f - true1) / true1
    return {
        "first_change_s": first,
        "design_changes": int(changed.size),
        "mean_hz": float(np.mean(f)),
        "median_hz_after_first_change": float(np.median(f[t >= first])) if changed.size else float("nan"),
        "min_hz": float(np.min(f)),
        "max_hz": float(np.max(f)),
        "median_rel_error_to_true_f1": float(np.median(rel)),
        "median_rel_error_after_first_change": float(np.median(rel[t >= first])) if changed.size else float("nan"),
        "time_within_10pct_of_true_f1": float(np.mean(rel <= 0.10)),
    }


def first_mode_over_run(record: RunRecord) -> dict[str, float]:
    """The true first-mode frequency over the run: mean, min, max and its spread in % of the mean
    (the mean is what a fixed OATF tuned right to the run is designed for)."""
    f1 = record.true_mode_hz(record.t_s, 0)
    return {
        "mean_f1_hz": float(np.mean(f1)),
        "min_f1_hz": float(np.min(f1)),
        "max_f1_hz": float(np.max(f1)),
        "variation_pct": float(100 * (f1.max() - f1.min()) / f1.mean()),
    }
