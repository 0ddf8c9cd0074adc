"""Unfiltered deflection costs against a reference's, pooled over both links, and the acceleration read several ways.

The thesis reports one figure per simulation group (§4.3); a two-link model
is compared pooled, ``sqrt((c1^2 + c2^2) / 2)``. Noise adds to the
trajectory-driven vibration in quadrature (independent), so its own part is
``sqrt(c_noisy^2 - c_clean^2)``. The §4.2.1 estimators (10-sample slope,
40-sample quadratic; ``controller.metrics``) bound the acceleration/velocity
ratio any sampled signal can show (:func:`estimator_ratio_bound`);
:func:`acceleration_readings` reads the same runs through those estimators,
through them on a finer log, and from the model's own state derivatives
(docs/simulation-calibration.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from controller.metrics import acceleration_filter, rms_costs, velocity_filter

__all__ = ["acceleration_readings", "baselines", "estimator_ratio_bound", "pooled"]

Pair = tuple[float, float]
"""(RMS deflection velocity in/s, acceleration in/s²)."""


def pooled(c: Sequence[float]) -> float:
    """Both links' cost as one figure: ``sqrt((c1^2 + c2^2) / 2)``."""
    return float(math.sqrt((c[0] ** 2 + c[1] ** 2) / 2.0))


def _noise_part(clean: Pair, noisy: Pair) -> list[float]:
    return [math.sqrt(max(noisy[i] ** 2 - clean[i] ** 2, 0.0)) for i in (0, 1)]


def baselines(unfiltered: Mapping[str, Mapping[str, list[float]]], reference: Mapping[str, Pair]) -> dict[str, Any]:
    """Per group key of ``reference`` (``group1`` clean, ``group2`` noisy: reference velocity and acceleration),
    the unfiltered costs per link (``unfiltered[key]["velocity_rms_in_s"]``, ``["acceleration_rms_in_s2"]``) and
    pooled, then the noise's part of each; with the noise part's acceleration/velocity ratio, measured and reference."""
    rows = []
    got: dict[str, Pair] = {}
    for gk, (tv, ta) in reference.items():
        v, a = unfiltered[gk]["velocity_rms_in_s"], unfiltered[gk]["acceleration_rms_in_s2"]
        got[gk] = (pooled(v), pooled(a))
        rows.append({"label": f"{gk} velocity", "link": v, "pooled": got[gk][0], "thesis": tv})
        rows.append({"label": f"{gk} acceleration", "link": a, "pooled": got[gk][1], "thesis": ta})
    clean, noisy = list(reference)
    inc = _noise_part(got[clean], got[noisy])
    tinc = [math.sqrt(reference[noisy][i] ** 2 - reference[clean][i] ** 2) for i in (0, 1)]
    rows.append({"label": "noise part, velocity", "link": [float("nan")] * 2, "pooled": inc[0], "thesis": tinc[0]})
    rows.append({"label": "noise part, acceleration", "link": [float("nan")] * 2, "pooled": inc[1], "thesis": tinc[1]})
    return {"rows": rows, "noise_ratio_rad_s": inc[1] / inc[0] if inc[0] > 0 else float("nan"), "thesis_noise_ratio_rad_s": tinc[1] / tinc[0]}


def _state_pooled(x: np.ndarray) -> float:
    """RMS (std over time, mean variance over runs) of ``(runs, n, 2)`` per link, pooled."""
    return pooled([float(np.sqrt(np.mean(np.var(x[:, :, j], axis=1)))) for j in (0, 1)])


def acceleration_readings(
    estimated: Mapping[int, Pair],
    state: Mapping[str, np.ndarray],
    index: Mapping[int, list[int]],
    reference: Mapping[int, Pair],
    fine_deflections: np.ndarray | None = None,
    fine_period_s: float = 0.0,
) -> dict[str, Any]:
    """Groups 1 (clean) and 2 (noisy) read several ways, pooled over both links, each with its noise part and
    acceleration/velocity ratios: ``estimators_200hz`` (the §4.2.1 estimators at the model's rate, ``estimated``),
    ``model_state_derivatives`` (RMS of the model's q' and q'', ``state["deflection_rate_in_s"]``,
    ``["deflection_accel_in_s2"]`` at the runs ``index[g]``, what a Simulink model outputs without any estimator),
    ``estimators_<rate>hz`` (the same estimators on ``fine_deflections``, ``(runs, n, 2)`` logged every
    ``fine_period_s``: group 1's runs then group 2's, as many as ``index`` has) and ``thesis`` (``reference``)."""
    stated = {g: (_state_pooled(state["deflection_rate_in_s"][index[g]]), _state_pooled(state["deflection_accel_in_s2"][index[g]])) for g in (1, 2)}
    readings_in: list[tuple[str, Mapping[int, Pair]]] = [("estimators_200hz", estimated), ("model_state_derivatives", stated), ("thesis", reference)]
    if fine_deflections is not None:
        costs = [rms_costs(d, fine_period_s) for d in fine_deflections]
        order = [g for g in (1, 2) for _ in index[g]]
        per = {g: [c for c, gg in zip(costs, order, strict=True) if gg == g] for g in (1, 2)}
        fine_c = {
            g: (pooled(np.mean([c.velocity_rms for c in per[g]], axis=0).tolist()), pooled(np.mean([c.acceleration_rms for c in per[g]], axis=0).tolist()))
            for g in (1, 2)
        }
        readings_in.insert(2, (f"estimators_{round(1 / fine_period_s):d}hz", fine_c))
    readings: dict[str, Any] = {}
    for name, c in readings_in:
        inc = _noise_part(c[1], c[2])
        readings[name] = {
            "group1_velocity_in_s": c[1][0],
            "group1_acceleration_in_s2": c[1][1],
            "group1_ratio_rad_s": c[1][1] / c[1][0],
            "group2_velocity_in_s": c[2][0],
            "group2_acceleration_in_s2": c[2][1],
            "noise_part_velocity_in_s": inc[0],
            "noise_part_acceleration_in_s2": inc[1],
            "noise_part_ratio_rad_s": inc[1] / inc[0] if inc[0] > 0 else float("nan"),
        }
    return readings


def estimator_ratio_bound(sample_period_s: float) -> dict[str, float]:
    """Largest ``|H_acc(f)| / |H_vel(f)|`` of the §4.2.1 estimators below the slope filter's first zero."""
    vf, af = velocity_filter(sample_period_s), acceleration_filter(sample_period_s)
    f = np.linspace(0.01, 0.5 / sample_period_s, 20001)
    gv = np.abs(vf.gain(f))
    first_zero = float(f[np.argmax(np.diff(gv) > 0)]) if np.any(np.diff(gv) > 0) else float(f[-1])
    m = f < 0.9 * first_zero
    r = 2 * np.pi * f[m] * np.abs(af.gain(f[m])) / gv[m]
    i = int(np.argmax(r))
    return {"max_ratio_rad_s": float(r[i]), "at_hz": float(f[m][i]), "first_zero_hz": first_zero}
