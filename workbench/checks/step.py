"""Step-response checks: settling into a band and overshoot.

Both measure a step from ``initial`` (the first sample from ``start_s`` on)
to ``final`` (the last sample), as ``control.step_info`` does for response
data; give ``final`` for a noisy signal. The band and the overshoot are
relative to the step's size ``|final - initial|``.
"""

from __future__ import annotations

import math

import numpy as np

from workbench.checks.collect import collected
from workbench.checks.result import Band, CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label, non_finite, window


def _step(sig: Signal, start_s: float | None, initial: float | None, final: float | None) -> tuple[Signal, float, float, float, str | None]:
    part, short = window(sig, start_s, 3)
    if short is None:
        short = non_finite(part)
    if short is not None:
        return part, math.nan, math.nan, math.nan, short
    t0 = float(part.t[0]) if start_s is None else float(start_s)
    y0 = float(part.values[0]) if initial is None else float(initial)
    yf = float(part.values[-1]) if final is None else float(final)
    return part, t0, y0, yf, None


def settles_within(
    sig: Signal,
    within_s: float,
    *,
    band_pct: float = 2.0,
    band: float | None = None,
    start_s: float | None = None,
    initial: float | None = None,
    final: float | None = None,
    name: str | None = None,
) -> CheckResult:
    """Does ``sig`` settle, within ``within_s`` seconds of ``start_s``, into a band around its
    final value and stay there? The band is ``±band`` in the signal's unit, or
    ``±band_pct`` % of the step's size (default 2 %). The settling time is the first
    sample after the last one outside the band (``control.step_info``'s); a signal
    still outside at its end never settled (measured: inf)."""
    title = name or label("settles_within", sig)
    part, t0, y0, yf, short = _step(sig, start_s, initial, final)
    if short is not None:
        return collected(invalid(title, short, within_s, "s"))
    half = float(band) if band is not None else band_pct / 100.0 * abs(yf - y0)
    if not half > 0:
        return collected(invalid(title, f"{sig.name} makes no step ({fmt(y0)} to {fmt(yf)} {sig.unit}); give band=", within_s, "s"))
    outside = np.flatnonzero(np.abs(part.values - yf) > half)
    if outside.size == 0:
        index = 0
    elif outside[-1] == len(part) - 1:
        index = -1
    else:
        index = int(outside[-1]) + 1
    settled = math.inf if index < 0 else float(part.t[index]) - t0
    at = (float(part.t[index]), float(part.values[index])) if index >= 0 else (math.nan, math.nan)
    data = FigureData(
        title,
        (
            Panel(
                f"{sig.name} ({sig.unit})" if sig.unit else sig.name,
                traces=(Trace(part.t, part.values, sig.name),),
                bands=(Band(part.t, np.full(len(part), yf - half), np.full(len(part), yf + half), f"final ±{fmt(half)} {sig.unit}"),),
                instants=((t0, f"start {fmt(t0)} s"),),
                vlines=((t0 + within_s, f"limit {fmt(within_s)} s"),),
                marks=(Mark(at[0], at[1], f"settled after {fmt(settled)} s"),),
            ),
        ),
    )
    band_text = f"±{fmt(half)} {sig.unit}".rstrip() + f" of {fmt(yf)} {sig.unit}".rstrip()
    if index < 0:
        sentence = f"{sig.name} never settled to {band_text}: still outside at {fmt(float(part.t[-1]))} s (limit {fmt(within_s)} s)"
    else:
        sentence = f"{sig.name} settled to {band_text} after {fmt(settled)} s against a limit of {fmt(within_s)} s"
    return collected(judged(title, settled <= within_s, settled, within_s, "s", sentence, data, {"final": yf, "band": half}))


def overshoot_below(
    sig: Signal,
    limit_pct: float,
    *,
    start_s: float | None = None,
    initial: float | None = None,
    final: float | None = None,
    name: str | None = None,
) -> CheckResult:
    """Is the overshoot of the step in ``sig`` at most ``limit_pct`` % of the step's size?
    Overshoot: how far the signal goes past its final value in the step's direction
    (0 when it never does), in % of ``|final - initial|``; for a second-order system
    ``100 exp(-ζπ/√(1-ζ²))``."""
    title = name or label("overshoot_below", sig)
    part, _t0, y0, yf, short = _step(sig, start_s, initial, final)
    if short is not None:
        return collected(invalid(title, short, limit_pct, "%"))
    size = yf - y0
    if size == 0:
        return collected(invalid(title, f"{sig.name} makes no step ({fmt(y0)} to {fmt(yf)} {sig.unit})", limit_pct, "%"))
    direction = 1.0 if size > 0 else -1.0
    past = direction * (part.values - yf)
    peak = int(np.argmax(past))
    overshoot = max(float(past[peak]), 0.0) / abs(size) * 100.0
    data = FigureData(
        title,
        (
            Panel(
                f"{sig.name} ({sig.unit})" if sig.unit else sig.name,
                traces=(Trace(part.t, part.values, sig.name),),
                hlines=((yf, f"final {fmt(yf)}"), (yf + direction * limit_pct / 100.0 * abs(size), f"limit {fmt(limit_pct)} %")),
                marks=(Mark(float(part.t[peak]), float(part.values[peak]), f"peak: {fmt(overshoot)} %"),),
            ),
        ),
    )
    sentence = f"overshoot {overshoot:.1f} % against a limit of {fmt(limit_pct)} % ({sig.name} peaked at {fmt(float(part.values[peak]))} {sig.unit} for a step of {fmt(size)} {sig.unit})"
    return collected(judged(title, overshoot <= limit_pct, overshoot, limit_pct, "%", " ".join(sentence.split()), data, {"peak_t_s": float(part.t[peak])}))
