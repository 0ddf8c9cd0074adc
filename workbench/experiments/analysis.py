"""The analysis the experiments share: costs over a stretch, running medians, lag crossings, spectrogram columns.

Pure functions of arrays (no rig, no files): the §4.2.1 costs over a masked
stretch of a run (:func:`costs_over`), a centred running median
(:func:`centred_median`) and moving average (:func:`moving_average`), the lag
of an identified track behind the truth as one whole-run shift
(:func:`alignment_lag`) and per big change (:func:`transition_lags`), and the
statistics of one spectrogram column against the true modes
(:func:`column_stats`) beside a plain spectrogram (:func:`plain_spectrogram`).
"""

from __future__ import annotations

import math
from typing import Literal, TypedDict

import numpy as np
import numpy.typing as npt
import scipy.signal as ss
from scipy.signal import ShortTimeFFT
from scipy.signal.windows import hann

from controller.metrics import deflection_acceleration, deflection_velocity

THESIS_BATCH_SIZE = 20
"""The batch size l the experiments use (thesis: 20-50 samples; its identification runs: 20)."""

LAG_STEP_S = 0.05
"""The step of the shifts :func:`alignment_lag` tries (s)."""


def costs_over(deflection: npt.ArrayLike, mask: npt.ArrayLike, sample_period_s: float = 0.005) -> dict[str, list[float]]:
    """The §4.2.1 costs (``controller.metrics``) over the samples where ``mask`` holds.

    The derivative estimates are taken on the whole run (centred regressions,
    full windows) and their standard deviation over the estimates whose time
    falls on a masked sample, so a stretch cut out of a run (a lap, the
    samples near the singularity) has no edge effects.
    """
    d = np.asarray(deflection, dtype=float)
    m = np.asarray(mask, dtype=bool)
    out: dict[str, list[float]] = {}
    for key, fn in (("velocity_rms", deflection_velocity), ("acceleration_rms", deflection_acceleration)):
        est = fn(d, sample_period_s)
        idx = np.clip(np.round(est.t_s / sample_period_s).astype(int), 0, m.size - 1)
        sel = est.values[m[idx]]
        out[key] = np.std(sel, axis=0).tolist() if sel.shape[0] > 1 else [float("nan")] * d.shape[1]
    out["samples"] = [int(m.sum())]
    return out


def centred_median(t: np.ndarray, f: np.ndarray, half_s: float, step: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Running median of ``f`` over ``[t - half_s, t + half_s]`` on every ``step``-th sample (NaNs ignored)."""
    dt = float(t[1] - t[0])
    h = int(round(half_s / dt))
    idx = np.arange(0, t.size, step)
    out = np.full(idx.size, np.nan)
    for k, i in enumerate(idx):
        w = f[max(0, i - h) : i + h + 1]
        w = w[np.isfinite(w)]
        if w.size:
            out[k] = np.median(w)
    return t[idx], out


def moving_average(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over ``n`` samples, edges padded with the end values."""
    n = max(1, int(n))
    ker = np.ones(n) / n
    return np.convolve(np.pad(x, (n // 2, n - 1 - n // 2), mode="edge"), ker, mode="valid")


class Alignment(TypedDict):
    """:func:`alignment_lag`: the median error against each shift, and the best shift."""

    lags_s: list[float]
    median_abs_error_hz: list[float]
    lag_s: float
    error_at_lag_hz: float
    error_at_zero_hz: float


class Transition(TypedDict):
    """One big change of the true first mode (:func:`transition_lags`)."""

    true_crossing_s: float
    from_hz: float
    to_hz: float
    level_hz: float
    direction: Literal["up", "down"]
    lag_s: float  #: NaN: the estimate was already past the level; ∞: not within the searched range


class IdentificationLag(TypedDict):
    """The identification lag as the report stores it."""

    alignment: Alignment
    transitions: list[Transition]
    median_transition_lag_s: float
    max_lag_searched_s: float


def alignment_lag(t: np.ndarray, f_id: np.ndarray, f_true: np.ndarray, max_lag_s: float, step_s: float = LAG_STEP_S) -> Alignment:
    """The shift τ ∈ [0, max_lag_s] minimising the median |f_id(t) − f_true(t − τ)| (``t`` uniform; NaNs ignored)."""
    lags = np.arange(0.0, max_lag_s + 1e-9, step_s)
    med = []
    for tau in lags:
        shifted = np.interp(t - tau, t, f_true, left=np.nan)
        ok = np.isfinite(shifted) & np.isfinite(f_id)
        med.append(float(np.median(np.abs(f_id[ok] - shifted[ok]))) if ok.sum() >= 40 else np.nan)
    med_a = np.array(med)
    i = int(np.nanargmin(med_a)) if np.isfinite(med_a).any() else 0
    return {
        "lags_s": lags.tolist(),
        "median_abs_error_hz": med_a.tolist(),
        "lag_s": float(lags[i]),
        "error_at_lag_hz": float(med_a[i]),
        "error_at_zero_hz": float(med_a[0]),
    }


def transition_lags(t: np.ndarray, f_smooth: np.ndarray, tm: np.ndarray, m: np.ndarray, t_min: float, prominence: float, max_lag_s: float) -> list[Transition]:
    """Lags at the big changes of the (smoothed) true first mode.

    A transition runs between consecutive extrema of ``f_smooth`` (prominence
    ≥ ``prominence``; the series' ends count when they differ enough); its
    time is where ``f_smooth`` crosses half-way.  The lag is the time from
    there until the identified running median ``m`` crosses the same level the
    same way (NaN when ``m`` was already past it, ∞ when not within
    ``max_lag_s``).  Transitions before ``t_min`` are skipped.
    """
    peaks, _ = ss.find_peaks(f_smooth, prominence=prominence)
    troughs, _ = ss.find_peaks(-f_smooth, prominence=prominence)
    ext = sorted(set(peaks.tolist()) | set(troughs.tolist()))
    for end in (0, f_smooth.size - 1):
        if not ext or abs(f_smooth[end] - f_smooth[ext[0] if end == 0 else ext[-1]]) >= prominence:
            ext = sorted(set(ext) | {end})
    out: list[Transition] = []
    for a, b in zip(ext[:-1], ext[1:]):
        fa, fb = float(f_smooth[a]), float(f_smooth[b])
        if abs(fb - fa) < prominence:
            continue
        level = 0.5 * (fa + fb)
        sign = 1.0 if fb > fa else -1.0
        seg = np.flatnonzero((f_smooth[a : b + 1] - level) * sign >= 0)
        t_cross = float(t[a + seg[0]])
        if t_cross < t_min:
            continue
        m_before = np.interp(t_cross - 0.5, tm, m)
        if not np.isfinite(m_before) or (m_before - level) * sign >= 0:
            lag = float("nan")
        else:
            after = np.flatnonzero((tm >= t_cross) & (tm <= t_cross + max_lag_s) & ((m - level) * sign >= 0))
            lag = float(tm[after[0]] - t_cross) if after.size else math.inf
        out.append({"true_crossing_s": t_cross, "from_hz": fa, "to_hz": fb, "level_hz": level, "direction": "up" if sign > 0 else "down", "lag_s": lag})
    return out


def column_stats(
    col_freqs: np.ndarray,
    power: np.ndarray,
    t_end: float,
    truth_t: np.ndarray,
    truth_f: np.ndarray,
    window_s: float,
    peak_band_hz: tuple[float, float],
    low_band_hz: float,
) -> tuple[bool, float, float, float]:
    """One spectrogram column (window ending at ``t_end``) against the true modes ``truth_f`` over that window:
    (its peak in ``peak_band_hz`` within 0.5 Hz of a true mode, the peak frequency, the column's share below
    ``low_band_hz``, the fraction of those bins valid); bins with zero power (the DSP's invalid bins) are left out."""
    m = (col_freqs >= peak_band_hz[0]) & (col_freqs <= peak_band_hz[1])
    if not np.any(power[m] > 0):
        return False, float("nan"), float("nan"), float("nan")
    fpk = float(col_freqs[m][np.argmax(power[m])])
    span = (truth_t > t_end - window_s) & (truth_t <= t_end)
    lo1, hi1 = truth_f[span, 0].min(), truth_f[span, 0].max()
    lo2, hi2 = truth_f[span, 1].min(), truth_f[span, 1].max()
    near = (lo1 - 0.5 <= fpk <= hi1 + 0.5) or (lo2 - 0.5 <= fpk <= hi2 + 0.5)
    low = (col_freqs > 0) & (col_freqs < low_band_hz)
    band = (col_freqs > 0) & (col_freqs <= peak_band_hz[1])
    share = float(power[low].sum() / power[band].sum()) if power[band].sum() > 0 else float("nan")
    return near, fpk, share, float(np.mean(power[low] > 0))


def plain_spectrogram(x: np.ndarray, width: int, fs_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A plain PSD spectrogram of ``x`` (mean removed; periodic Hann of ``width`` samples, 1 s hop, full windows only,
    ``scipy.signal.ShortTimeFFT``): ``(power (n_freqs, n_columns), each window's end time, frequencies)``."""
    x = x - x.mean()
    sft = ShortTimeFFT(hann(width, sym=False), hop=int(fs_hz), fs=fs_hz, scale_to="psd")
    p0 = sft.lower_border_end[1]
    p1 = sft.upper_border_begin(x.size)[1]
    sx = sft.spectrogram(x, p0=p0, p1=p1)
    st_end = sft.t(x.size, p0=p0, p1=p1) + (width / 2) / fs_hz  # drawn at the window's end, like a download
    return sx, st_end, sft.f
