"""How long an identified mode takes to follow a discontinuous change of the true one (thesis §5.3).

An identified frequency ``f(t)`` (one estimate per controller tick, held
between interrupts) is compared with the plant's ground truth ``f_true(t)``
through its centred running median ``m(t)`` over ±``MEDIAN_HALF_S``
(:func:`workbench.experiments.analysis.centred_median`; a centred median adds
no delay to a step). After each event at ``t_e`` (until the next event or the
end):

* **delay to 2 %**: the first time from which ``m`` stays within ``tolerance``
  of the new truth for ``HOLD_S`` (∞ if never);
* **delay to stay within 2 %**: the time after which ``m`` stays within the
  tolerance up to the next event, less the median's half window (∞ if outside
  there);
* **delay to 50 %**: the first time ``m`` crosses half-way from the old to the
  new true frequency (NaN when ``m`` was not on the old side at the event);
* the first raw estimate inside the band and the error before the event.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from workbench.experiments.analysis import centred_median
from workbench.hil import RunRecord

__all__ = [
    "HOLD_S",
    "MEDIAN_HALF_S",
    "STEADY_AFTER_S",
    "TOLERANCE",
    "event_delays",
    "payload_switch_times",
    "record_delays",
    "series_delays",
    "steady_share",
]

TOLERANCE = 0.02
"""Relative band around the true frequency."""
HOLD_S = 2.0
"""How long the running median must stay in the band to count as settled (s)."""
MEDIAN_HALF_S = 1.0
"""Half window of the centred running median (s)."""
STEADY_AFTER_S = 8.0
"""The steady stretch of an event's interval starts this long after it (:func:`steady_share`)."""


def event_delays(
    t: np.ndarray, f: np.ndarray, true1: np.ndarray, tm: np.ndarray, m: np.ndarray, at_s: float, until_s: float, tolerance: float = TOLERANCE
) -> dict[str, Any]:
    """Delays after one event at ``at_s`` (the next event or the run's end at ``until_s``): raw series ``f``
    at ``t``, truth ``true1``, running median ``m`` at ``tm`` (see the module doc)."""
    before = (t >= at_s - 8.0) & (t < at_s)
    old = float(np.median(true1[before]))
    new = float(np.median(true1[(t >= at_s + 1.0) & (t < until_s)]))
    half = 0.5 * (old + new)
    sign = 1.0 if new > old else -1.0
    win = (tm >= at_s) & (tm < until_s)
    tw, mw = tm[win], m[win]
    truth_w = np.interp(tw, t, true1)
    inside = np.abs(mw - truth_w) / truth_w <= tolerance
    dt = float(tm[1] - tm[0])
    hold = int(round(HOLD_S / dt))
    settle = math.inf
    for k in range(max(0, inside.size - hold)):
        if inside[k : k + hold + 1].all():
            settle = float(tw[k] - at_s)
            break
    # stays within the tolerance up to the next event: the median's last second before it already sees it
    upto = tw < until_s - MEDIAN_HALF_S
    outside = np.flatnonzero(~inside[upto])
    if not upto.any() or (outside.size and outside[-1] == upto.sum() - 1):
        stays = math.inf
    else:
        stays = float(tw[outside[-1] + 1] - at_s) if outside.size else float(tw[0] - at_s)
    m_at = np.interp(at_s - 0.5, tm, m)  # the running median just before the event
    valid_start = bool(np.isfinite(m_at)) and (m_at - half) * sign < 0
    cross = np.flatnonzero((mw - half) * sign >= 0)
    half_delay = float(tw[cross[0]] - at_s) if (valid_start and cross.size) else (math.inf if valid_start else float("nan"))
    raw_in = np.flatnonzero((t >= at_s) & (t < until_s) & (np.abs(f - true1) / true1 <= tolerance))
    pre_f = f[before & np.isfinite(f)]
    return {
        "at_s": at_s,
        "kind": "release" if new > old else "attach",
        "true_before_hz": old,
        "true_after_hz": new,
        "step_pct": 100.0 * (new - old) / old,
        "settle_2pct_s": settle,
        "stays_2pct_s": stays,
        "delay_50pct_s": half_delay,
        "started_on_the_old_side": valid_start,
        "first_raw_in_band_s": float(t[raw_in[0]] - at_s) if raw_in.size else math.inf,
        "median_rel_error_before": float(np.median(np.abs(pre_f - old) / old)) if pre_f.size else float("nan"),
    }


def series_delays(t: np.ndarray, f: np.ndarray, true1: np.ndarray, events_s: Sequence[float], tolerance: float = TOLERANCE) -> dict[str, Any]:
    """Every event's delays (:func:`event_delays`) for one identified series ``f`` at times ``t`` against the
    truth ``true1``, and their summary (median over events; ∞ counts as the largest)."""
    tm, m = centred_median(t, f, MEDIAN_HALF_S)
    ends = list(events_s[1:]) + [float(t[-1])]
    events = [event_delays(t, f, true1, tm, m, a, b, tolerance) for a, b in zip(events_s, ends)]
    settle = np.array([e["settle_2pct_s"] for e in events])
    stays = np.array([e["stays_2pct_s"] for e in events])
    half = np.array([e["delay_50pct_s"] for e in events])
    half_ok = half[np.isfinite(half)]
    end = (t >= t[-1] - 8.0) & np.isfinite(f)
    rel_end = np.abs(f[end] - true1[end]) / true1[end]
    first_estimate = float(t[np.flatnonzero(np.isfinite(f))[0]]) if np.isfinite(f).any() else float("nan")
    return {
        "events": events,
        "settled_events": int(np.isfinite(settle).sum()),
        "median_settle_2pct_s": float(np.median(settle)) if settle.size else float("nan"),
        "max_settle_2pct_s": float(np.max(settle)) if settle.size else float("nan"),
        "stayed_events": int(np.isfinite(stays).sum()),
        "median_stays_2pct_s": float(np.median(stays)) if stays.size else float("nan"),
        "median_delay_50pct_s": float(np.median(half_ok)) if half_ok.size else float("nan"),
        "measurable_50pct_events": int(half_ok.size),
        "median_rel_error_end": float(np.median(rel_end)) if rel_end.size else float("nan"),
        "first_estimate_s": first_estimate,
        "median_series": {"t_s": tm.tolist(), "f_hz": m.tolist()},
    }


def payload_switch_times(res: RunRecord) -> list[float]:
    """The times the plant's ground truth shows the payload attached or released (controller time)."""
    truth_t = np.asarray(res.truth_columns["sim_time_s"]) - res.sample_period_s
    attached = np.asarray(res.truth_columns["payload_attached"]).astype(bool)
    switch = np.flatnonzero(attached[:-1] != attached[1:])
    return [float(truth_t[i + 1]) for i in switch]


def record_delays(res: RunRecord, events_s: Sequence[float], tolerance: float = TOLERANCE) -> dict[str, Any]:
    """Every event's delays for one run (:func:`series_delays` of the record's identified first pole ``f_id_hz``
    against the true first mode), the payload switches the plant applied and the median confidence after the first event."""
    t = res.t_s
    f = np.asarray(res.columns["f_id_hz"], dtype=float)
    conf = np.asarray(res.columns["id_confidence"], dtype=float)
    out = series_delays(t, f, res.true_mode_hz(t, 0), events_s, tolerance)
    out["events_applied_s"] = payload_switch_times(res)
    out["median_confidence"] = float(np.median(conf[t >= events_s[0]]))
    return out


def steady_share(t: np.ndarray, f: np.ndarray, true1: np.ndarray, events: Sequence[float], tolerance: float = TOLERANCE) -> float:
    """The share of the time from ``STEADY_AFTER_S`` after each event to the next (or the end, less the median's
    half window) in which the centred running median of ``f`` is within ``tolerance`` of the truth: the
    estimator's floor against the criterion, with no change to follow. Below 1, no reset can make the
    hold of ``HOLD_S`` certain."""
    tm, m = centred_median(t, f, MEDIAN_HALF_S)
    truth = np.interp(tm, t, true1)
    ends = [*events[1:], float(t[-1])]
    sel = np.zeros(tm.size, dtype=bool)
    for a, b in zip(events, ends):
        sel |= (tm >= a + STEADY_AFTER_S) & (tm < b - MEDIAN_HALF_S)
    ok = sel & np.isfinite(m)
    return float(np.mean(np.abs(m[ok] - truth[ok]) / truth[ok] <= tolerance)) if ok.any() else float("nan")
