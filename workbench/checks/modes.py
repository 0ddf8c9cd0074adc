"""Identification: an identified modal frequency against the truth."""

from __future__ import annotations

import numpy as np

from workbench.checks.collect import collected
from workbench.checks.result import Band, CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label, window


def mode_frequency_within(
    identified: Signal,
    truth: Signal | float,
    *,
    rel_tol: float | None = None,
    abs_tol: float | None = None,
    from_s: float | None = None,
    max_missing: float = 0.0,
    name: str | None = None,
) -> CheckResult:
    """Is every identified frequency from ``from_s`` on within ``rel_tol`` (a fraction:
    0.05 is 5 %) or ``abs_tol`` (the signal's unit) of the truth, a value or a series
    (taken at the identified samples' times, linear interpolation)? A sample that
    identified nothing (NaN) is missing: more than ``max_missing`` (a fraction) of them fails.
    Give exactly one of ``rel_tol`` and ``abs_tol``."""
    if (rel_tol is None) == (abs_tol is None):
        raise ValueError("mode_frequency_within: give exactly one of rel_tol (a fraction) and abs_tol (in the signal's unit)")
    truth_name = truth.name if isinstance(truth, Signal) else fmt(float(truth))
    title = name or label("mode_frequency_within", identified, truth_name)
    relative = rel_tol is not None
    limit = 100.0 * float(rel_tol) if rel_tol is not None else float(abs_tol or 0.0)
    unit = "%" if relative else identified.unit
    part, short = window(identified, from_s, 1)
    if short is None and isinstance(truth, Signal) and len(truth) == 0:
        short = f"the truth {truth.name} has no sample"
    if short is not None:
        return collected(invalid(title, short, limit, unit))
    found = np.isfinite(part.values)
    if not found.any():
        return collected(invalid(title, f"{identified.name} identified nothing in its {len(part)} samples from {fmt(float(part.t[0]))} s on", limit, unit))
    true = np.interp(part.t, truth.t, truth.values) if isinstance(truth, Signal) else np.full(len(part), float(truth))
    error = part.values - true
    size = np.abs(error) / np.abs(true) * 100.0 if relative else np.abs(error)
    size = np.where(found, size, -np.inf)
    worst = int(np.argmax(size))
    measured = float(size[worst])
    missing = 1.0 - float(np.count_nonzero(found)) / len(part)
    half = np.abs(true) * float(rel_tol) if rel_tol is not None else np.full(len(part), float(abs_tol or 0.0))
    truth_trace = (Trace(truth.t, truth.values, truth.name),) if isinstance(truth, Signal) else ()
    data = FigureData(
        title,
        (
            Panel(
                f"frequency ({identified.unit})" if identified.unit else "frequency",
                traces=(*truth_trace, Trace(part.t, part.values, identified.name, "points")),
                bands=(Band(part.t, true - half, true + half, f"truth ±{fmt(limit)} {unit}"),),
                marks=(Mark(float(part.t[worst]), float(part.values[worst]), f"worst {fmt(measured)} {unit}"),),
            ),
        ),
    )
    ok = measured <= limit and missing <= max_missing
    counted = f"{np.count_nonzero(found)} of {len(part)} samples identified"
    sentence = (
        f"{identified.name} within {fmt(measured)} {unit} of {truth_name} at worst against a tolerance of {fmt(limit)} {unit} "
        f"from {fmt(float(part.t[0]))} s on ({counted}" + (f", more missing than the {fmt(100 * max_missing)} % allowed)" if missing > max_missing else ")")
    )
    return collected(judged(title, ok, measured, limit, unit, sentence, data, {"missing_fraction": missing, "t_s": float(part.t[worst])}))
