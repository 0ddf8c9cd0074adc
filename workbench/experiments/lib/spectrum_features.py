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


def magnitude_agreement(freqs: np.ndarray, reference_mag: np.ndarray, other: np.ndarray, band: tuple[float, float]) -> dict[str, float | int]:
    """How closely ``|other|`` matches ``reference_mag`` on the bins where the reference is non-zero.

    Relative differences ``||other| − ref| / ref``: their median, 99th
    percentile and maximum over those bins, the maximum within ``band``
    (NaN if no such bin there), and the number of bins compared.
    """
    valid = reference_mag > 0
    rel = np.abs(np.abs(other[valid]) - reference_mag[valid]) / reference_mag[valid]
    inband = valid & (freqs >= band[0]) & (freqs <= band[1])
    rel_band = np.abs(np.abs(other[inband]) - reference_mag[inband]) / reference_mag[inband]
    return {
        "valid_bins": int(valid.sum()),
        "median_rel_diff": float(np.median(rel)),
        "p99_rel_diff": float(np.percentile(rel, 99)),
        "max_rel_diff": float(rel.max()),
        f"max_rel_diff_{band[0]:g}_{band[1]:g}Hz": float(rel_band.max()) if rel_band.size else float("nan"),
    }
