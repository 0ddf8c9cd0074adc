"""Tracking: does a signal follow its reference, within a lag and a tolerance?"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt
from scipy import signal as sps

from workbench.checks.collect import collected
from workbench.checks.result import Band, CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label, non_finite, window

MIN_SAMPLES = 8


def estimate_lag(reference: npt.NDArray[np.float64], actual: npt.NDArray[np.float64], max_shift: int) -> tuple[int, npt.NDArray[np.float64]]:
    """The shift ``k`` (samples, ``|k| <= max_shift``) at which ``actual[n + k]`` best matches
    ``reference[n]``: positive when ``actual`` lags. From the cross-correlation of the two
    (``scipy.signal.correlate``) over a fixed stretch of the reference, with each shift's
    energy of ``actual``: the mean squared difference per shift is
    ``(Σa² - 2 Σa·r + Σr²) / m``, least at the lag. Returns the lag and those mean squares."""
    n = min(reference.size, actual.size)
    m = n - 2 * max_shift
    offset = float(np.mean(reference[:n]))
    r = reference[max_shift : n - max_shift] - offset
    a = actual[:n] - offset
    cross = sps.correlate(a, r, mode="valid")  # cross[j] = Σ_i a[i + j] r[i], j = 0 .. 2 max_shift
    squares = np.concatenate([[0.0], np.cumsum(a * a)])
    energy = squares[m : m + 2 * max_shift + 1] - squares[: 2 * max_shift + 1]
    mse = (energy - 2.0 * cross + float(np.dot(r, r))) / m
    return int(np.argmin(mse)) - max_shift, mse


def follows_reference(
    reference: Signal,
    actual: Signal,
    *,
    tolerance: float,
    max_lag_s: float,
    start_s: float | None = None,
    search_s: float | None = None,
    name: str | None = None,
) -> CheckResult:
    """Does ``actual`` follow ``reference`` with a lag of at most ``max_lag_s`` and, once
    shifted back by that lag, an error of at most ``tolerance`` (the signals' unit) at
    every sample? The lag is estimated by cross-correlation (:func:`estimate_lag`,
    one sample's resolution, searched over ``±search_s``, default twice ``max_lag_s``);
    ``actual`` is taken at the reference's times (linear interpolation), from ``start_s`` on.
    A reference constant over the window has no lag to find: the lag is then 0."""
    title = name or label("follows_reference", reference, actual)
    if reference.unit and actual.unit and reference.unit != actual.unit:
        raise ValueError(f"follows_reference: {reference.name} is in {reference.unit}, {actual.name} in {actual.unit}; compare signals in one unit")
    ref, short = window(reference, start_s, MIN_SAMPLES)
    act, short_a = window(actual, start_s, MIN_SAMPLES)
    problem = short or short_a or non_finite(ref) or non_finite(act)
    if problem is not None:
        return collected(invalid(title, problem, tolerance, reference.unit))
    lo, hi = max(ref.t[0], act.t[0]), min(ref.t[-1], act.t[-1])
    keep = (ref.t >= lo) & (ref.t <= hi)
    t, r = ref.t[keep], ref.values[keep]
    if t.size < MIN_SAMPLES:
        return collected(
            invalid(title, f"{reference.name} and {actual.name} overlap in {t.size} samples, at least {MIN_SAMPLES} needed", tolerance, reference.unit)
        )
    dt = float(np.median(np.diff(t)))
    a = np.interp(t, act.t, act.values)
    max_shift = min(max(1, math.ceil((search_s if search_s is not None else 2.0 * max_lag_s) / dt - 1e-9)), (t.size - MIN_SAMPLES) // 2)
    if max_shift < 1:
        return collected(invalid(title, f"{t.size} samples leave no room to search a lag", tolerance, reference.unit))
    flat = float(np.ptp(r)) == 0.0
    k = 0 if flat else estimate_lag(r, a, max_shift)[0]  # a constant reference has no lag to find
    lag = k * dt
    ref_part = r[max(-k, 0) : r.size - max(k, 0)]
    act_part = a[max(k, 0) : a.size - max(-k, 0)]
    t_part = t[max(-k, 0) : t.size - max(k, 0)]
    error = act_part - ref_part
    worst = int(np.argmax(np.abs(error)))
    peak = float(abs(error[worst]))
    at_edge = abs(k) == max_shift
    lag_ok = abs(lag) <= max_lag_s
    unit = reference.unit
    data = FigureData(
        title,
        (
            Panel(
                f"{reference.name}, {actual.name} ({unit})" if unit else f"{reference.name}, {actual.name}",
                traces=(Trace(t, r, reference.name), Trace(t, a, actual.name)),
                bands=(Band(t_part + lag, ref_part - tolerance, ref_part + tolerance, f"reference {fmt(lag * 1e3)} ms later ±{fmt(tolerance)}"),),
            ),
            Panel(
                f"error after the lag ({unit})" if unit else "error after the lag",
                traces=(Trace(t_part, error, f"{actual.name} - {reference.name}, shifted"),),
                hlines=((tolerance, f"±{fmt(tolerance)} {unit}".rstrip()), (-tolerance, "")),
                marks=(Mark(float(t_part[worst]), float(error[worst]), f"largest {fmt(peak)}"),),
            ),
        ),
    )
    if flat:
        behind = f"the constant {reference.name} (no lag to estimate)"
    else:
        behind = f"{reference.name} {'at least ' if at_edge else ''}{fmt(lag * 1e3)} ms behind (limit {fmt(max_lag_s * 1e3)} ms)"
    sentence = f"{actual.name} follows {behind} with a largest error of {fmt(peak)} {unit} after the lag against a tolerance of {fmt(tolerance)} {unit}"
    details = {"lag_s": lag, "rms_error": float(np.sqrt(np.mean(error * error))), "samples": float(error.size)}
    return collected(judged(title, lag_ok and peak <= tolerance, peak, tolerance, unit, " ".join(sentence.split()), data, details))
