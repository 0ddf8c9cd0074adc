"""The DSP's identified modes and the OATF's design against the plant's own truth (thesis §2.4).

The ETFE resolves one FFT bin (fs / N: 200 Hz / 2048) and lags true changes
by 1-4 s (its exponential averaging), so an identified first mode is judged
both at the same instant and against the values the truth took over the last
``lag_s`` widened by a bin. Every statistic counts the ticks after
``settle_s`` (the DSP's first full history).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from workbench.rig_record import RunRecord

BIN_HZ = 200.0 / 2048
"""One FFT bin at the thesis's settings (fs = 200 Hz, N = 2048)."""


def identification_against_truth(record: RunRecord, settle_s: float, lag_s: float = 4.0, bin_hz: float = BIN_HZ) -> dict[str, Any]:
    """The identified first mode's error (median, 90th percentile; share of ticks within ``bin_hz`` of
    the truth's range over the last ``lag_s``), the second mode's median relative error, the identified
    damping (median, 10th-90th percentile) against the truth's, and the OATF design's median relative
    error to the true first mode, all after ``settle_s``."""
    t = record.t_s
    late = t > settle_s
    f1, f2, zeta, oatf = (np.asarray(record.columns[k], dtype=float) for k in ("f_id_hz", "f_id2_hz", "zeta_id", "oatf_hz"))
    true1, true2 = record.true_mode_hz(t, 0), record.true_mode_hz(t, 1)
    valid = np.flatnonzero(np.isfinite(f1) & late)
    err = np.abs(f1[valid] - true1[valid])
    inside = [true1[(t >= t[k] - lag_s) & (t <= t[k])].min() - bin_hz <= f1[k] <= true1[(t >= t[k] - lag_s) & (t <= t[k])].max() + bin_hz for k in valid]
    ok2 = np.isfinite(f2) & late
    z = zeta[np.isfinite(zeta) & late]
    cols = record.truth_columns
    true_zeta = np.asarray(cols["damping_ratios"], dtype=float)[:, 0] if "damping_ratios" in cols else np.array([np.nan])
    return {
        "true_f1_range_hz": [float(true1[late].min()), float(true1[late].max())],
        "identified_share": float(valid.size / max(1, int(late.sum()))),
        "f1_median_abs_error_hz": float(np.median(err)) if err.size else float("nan"),
        "f1_p90_abs_error_hz": float(np.percentile(err, 90)) if err.size else float("nan"),
        "f1_within_bin_of_lagged_truth": float(np.mean(inside)) if inside else float("nan"),
        "f2_median_rel_error": float(np.median(np.abs(f2[ok2] - true2[ok2]) / true2[ok2])) if ok2.any() else float("nan"),
        "zeta_median": float(np.median(z)) if z.size else float("nan"),
        "zeta_p10_p90": [float(x) for x in np.percentile(z, [10, 90])] if z.size else [float("nan")] * 2,
        "true_zeta": float(np.median(true_zeta)),
        "oatf_median_rel_error": float(np.median(np.abs(oatf[late] - true1[late]) / true1[late])),
    }
