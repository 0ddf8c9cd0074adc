"""Amplitude checks: a signal stays within a band, its RMS stays under a limit."""

from __future__ import annotations

import math

import numpy as np

from workbench.checks.collect import collected
from workbench.checks.result import Band, CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label, non_finite, window


def _ylabel(sig: Signal) -> str:
    return f"{sig.name} ({sig.unit})" if sig.unit else sig.name


def stays_within(sig: Signal, low: float, high: float, *, from_s: float | None = None, name: str | None = None) -> CheckResult:
    """Does every sample of ``sig`` from ``from_s`` on lie in ``[low, high]``? Measured: the
    sample nearest to (or farthest past) an edge, judged against that edge; a non-finite
    sample is outside."""
    title = name or label("stays_within", sig)
    if not low <= high:
        raise ValueError(f"stays_within: low {low} is above high {high}")
    part, short = window(sig, from_s, 1)
    if short is not None:
        return collected(invalid(title, short, high, sig.unit))
    v = part.values
    margin = np.where(np.isfinite(v), np.minimum(v - low, high - v), -math.inf)
    i = int(np.argmin(margin))
    edge = low if np.isfinite(v[i]) and v[i] - low < high - v[i] else high
    outside = int(np.count_nonzero(margin < 0))
    unit = f" {sig.unit}" if sig.unit else ""
    since = f" from {fmt(float(part.t[0]))} s on"
    data = FigureData(
        title,
        (
            Panel(
                _ylabel(sig),
                traces=(Trace(part.t, v, sig.name),),
                bands=(Band(part.t, np.full(len(part), low), np.full(len(part), high), f"[{fmt(low)}, {fmt(high)}]{unit}"),),
                marks=(Mark(float(part.t[i]), float(v[i]), f"{fmt(float(v[i]))}{unit} at {fmt(float(part.t[i]))} s"),),
            ),
        ),
    )
    if outside:
        sentence = f"{sig.name} left [{fmt(low)}, {fmt(high)}]{unit}{since}: {fmt(float(v[i]))}{unit} at {fmt(float(part.t[i]))} s, {outside} of {len(part)} samples outside"
    else:
        sentence = f"{sig.name} stayed within [{fmt(low)}, {fmt(high)}]{unit}{since}, nearest its edge {fmt(float(v[i]))}{unit} at {fmt(float(part.t[i]))} s"
    return collected(judged(title, outside == 0, float(v[i]), edge, sig.unit, sentence, data, {"samples_outside": float(outside), "t_s": float(part.t[i])}))


def rms_below(sig: Signal, limit: float, *, from_s: float | None = None, remove_mean: bool = False, name: str | None = None) -> CheckResult:
    """Is the root mean square of ``sig`` from ``from_s`` on at most ``limit`` (about its mean
    when ``remove_mean``: the standard deviation)?"""
    title = name or label("rms_below", sig)
    part, short = window(sig, from_s, 2)
    problem = short or non_finite(part)
    if problem is not None:
        return collected(invalid(title, problem, limit, sig.unit))
    v = part.values - (float(np.mean(part.values)) if remove_mean else 0.0)
    rms = float(np.sqrt(np.mean(v * v)))
    centre = float(np.mean(part.values)) if remove_mean else 0.0
    unit = f" {sig.unit}" if sig.unit else ""
    mid = float(part.t[len(part) // 2])
    data = FigureData(
        title,
        (
            Panel(
                _ylabel(sig),
                traces=(Trace(part.t, part.values, sig.name),),
                bands=(Band(part.t, np.full(len(part), centre - limit), np.full(len(part), centre + limit), f"±{fmt(limit)}{unit} (limit)"),),
                hlines=((centre + rms, f"RMS {fmt(rms)}{unit}"), (centre - rms, "")),
                marks=(Mark(mid, centre + rms, f"RMS {fmt(rms)}"),),
            ),
        ),
    )
    about = " about its mean" if remove_mean else ""
    sentence = f"RMS of {sig.name}{about} {fmt(rms)}{unit} over {len(part)} samples from {fmt(float(part.t[0]))} s on against a limit of {fmt(limit)}{unit}"
    return collected(judged(title, rms <= limit, rms, limit, sig.unit, sentence, data, {"samples": float(len(part))}))
