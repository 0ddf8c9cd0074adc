"""Features of a magnitude spectrum: its dominant peak, its roughness across bins, the band around a frequency below a level."""

from __future__ import annotations

import numpy as np


def dominant_peak_hz(freqs: np.ndarray, mag: np.ndarray, valid: np.ndarray, band: tuple[float, float]) -> float:
    """The frequency of the largest ``mag`` in ``band`` on ``valid`` bins with ``mag`` > 0 (NaN if none)."""
    sel = (freqs >= band[0]) & (freqs <= band[1]) & valid & (mag > 0)
    if not sel.any():
        return float("nan")
    return float(freqs[sel][np.argmax(mag[sel])])


def roughness_db(freqs: np.ndarray, mag: np.ndarray, valid: np.ndarray, band: tuple[float, float]) -> float:
    """RMS second difference of 20 log10 ``mag`` over the contiguous runs (≥ 3 bins) of valid bins in ``band`` (dB; NaN if none)."""
    sel = (freqs >= band[0]) & (freqs <= band[1]) & valid & (mag > 0)
    idx = np.flatnonzero(sel)
    diffs = []
    for run in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
        if run.size >= 3:
            diffs.append(np.diff(20 * np.log10(mag[run]), 2))
    if not diffs:
        return float("nan")
    d = np.concatenate(diffs)
    return float(np.sqrt(np.mean(d**2)))


def band_below(freqs: np.ndarray, mag: np.ndarray, centre: float, level: float) -> tuple[float, float] | None:
    """The contiguous band of grid points around ``centre`` where ``mag <= level`` (grid resolution), or None if ``mag`` there is above it."""
    below = mag <= level
    k = int(np.argmin(np.abs(freqs - centre)))
    if not below[k]:
        return None
    lo = k
    while lo > 0 and below[lo - 1]:
        lo -= 1
    hi = k
    while hi < below.size - 1 and below[hi + 1]:
        hi += 1
    return float(freqs[lo]), float(freqs[hi])
