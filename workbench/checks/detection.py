"""Detection latency: an effect within a time after its cause."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from workbench.checks.collect import collected
from workbench.checks.result import CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label


def _first_true(sig: Signal, after_s: float) -> int | None:
    hits = np.flatnonzero((sig.t >= after_s) & np.isfinite(sig.values) & (sig.values != 0))
    return int(hits[0]) if hits.size else None


def detected_within(cause: Signal | float, detection: Signal, within_s: float, *, name: str | None = None) -> CheckResult:
    """Is there a detection within ``within_s`` seconds of the cause? The cause is a time
    (s) or the first non-zero sample of a signal (an event: ``events.payload``); the
    detection is the first non-zero sample of ``detection`` at or after it (an event,
    or a condition made with :meth:`Signal.where`). Measured: the latency. A cause that
    never came, or a detection series that ends before the limit without one, compared
    nothing."""
    cause_name = cause.name if isinstance(cause, Signal) else f"t={fmt(float(cause))} s"
    title = name or label("detected_within", cause_name, detection)
    if isinstance(cause, Signal):
        first = _first_true(cause, -math.inf)
        if first is None:
            return collected(invalid(title, f"the cause {cause.name} never came ({len(cause)} samples)", within_s, "s"))
        t_cause = float(cause.t[first])
    else:
        t_cause = float(cause)
    hit = _first_true(detection, t_cause)
    if detection.kind == "series" and (len(detection) == 0 or (hit is None and float(detection.t[-1]) < t_cause + within_s)):
        end = f"ends at {fmt(float(detection.t[-1]))} s" if len(detection) else "has no sample"
        return collected(invalid(title, f"{detection.name} {end}, before the limit {fmt(t_cause + within_s)} s, without a detection", within_s, "s"))
    latency = math.inf if hit is None else float(detection.t[hit]) - t_cause
    style: Literal["points", "step"] = "points" if detection.kind == "events" else "step"
    data = FigureData(
        title,
        (
            Panel(
                detection.name,
                traces=(Trace(detection.t, detection.values, detection.name, style),),
                instants=((t_cause, f"cause {cause_name}"),),
                vlines=((t_cause + within_s, f"limit {fmt(within_s)} s"),),
                marks=(Mark(float(detection.t[hit]), float(detection.values[hit]), f"detected after {fmt(latency)} s"),) if hit is not None else (),
            ),
        ),
    )
    if hit is None:
        sentence = f"no {detection.name} after the cause {cause_name} at {fmt(t_cause)} s (limit {fmt(within_s)} s)"
    else:
        sentence = f"{detection.name} {fmt(latency)} s after the cause {cause_name} at {fmt(t_cause)} s against a limit of {fmt(within_s)} s"
    return collected(judged(title, latency <= within_s, latency, within_s, "s", sentence, data, {"cause_t_s": t_cause}))
