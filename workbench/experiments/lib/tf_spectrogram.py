"""Spectrograms of an identifier's transfer-function downloads against a plain spectrogram of the output (thesis §4.2.2).

The DSP's downloads of |H11|, |H12|, |H21|, |H22|, |H_tot| in a row are a
spectrogram of the plant's transfer functions: each column the estimate
available at its download time. A plain spectrogram of a deflection
(:func:`~workbench.experiments.analysis.plain_spectrogram`) does not divide
out the input's spectrum. :func:`clutter` measures the difference (where each
column peaks against the true modes, and its share at low frequency);
:func:`spectrogram_figure` draws them side by side with the true modes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from workbench.experiments.analysis import column_stats
from workbench.experiments.report import new_figure

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["TF_NAMES", "Clutter", "ColumnStats", "clutter", "downloads_with_estimate", "spectrogram_figure"]

TF_NAMES = ("H11", "H12", "H21", "H22", "Htot")

ColumnStats = tuple[bool, float, float, float]
"""One spectrogram column (:func:`~workbench.experiments.analysis.column_stats`): peak near a true mode, peak
frequency, share below the low band, fraction of those bins valid."""


@dataclass(frozen=True)
class Clutter:
    """Where the spectrogram columns peak, for |H_tot| (``tf_``) and the plain deflection spectrogram (``st_``)."""

    tf_cols: list[ColumnStats]
    st_cols: list[ColumnStats]
    tf_near: float
    """Share of the columns peaking within 0.5 Hz of a true mode."""
    st_near: float
    tf_low: float
    """Median share of a column below the low band."""
    st_low: float
    tf_low_valid: float
    """Fraction of the |H_tot| bins below the low band that the DSP solved."""


def downloads_with_estimate(tf: dict[str, np.ndarray]) -> np.ndarray:
    """Per download, whether it holds an estimate (any |H_tot| bin above zero)."""
    return np.array([np.any(tf["Htot_mag"][i] > 0) for i in range(np.asarray(tf["sim_time_s"]).size)])


def clutter(
    tf: dict[str, np.ndarray],
    plain: tuple[np.ndarray, np.ndarray, np.ndarray],
    truth_t: np.ndarray,
    truth_f: np.ndarray,
    window_s: float,
    peak_band_hz: tuple[float, float],
    low_band_hz: float,
) -> Clutter:
    """Where each spectrogram column peaks (``peak_band_hz``) against the true modes over its ``window_s`` window,
    and its share below ``low_band_hz``, for the downloads' |H_tot|² and the ``plain`` spectrogram ``(power,
    window end times, frequencies)`` from the first download with an estimate on."""
    sx, st_end, sf = plain
    freqs = np.asarray(tf["freqs_hz"])
    dl_t = np.asarray(tf["sim_time_s"])
    has = downloads_with_estimate(tf)

    def column(col_freqs: np.ndarray, power: np.ndarray, t_end: float) -> ColumnStats:
        return column_stats(col_freqs, power, t_end, truth_t, truth_f, window_s, peak_band_hz, low_band_hz)

    tf_cols = [column(freqs, np.asarray(tf["Htot_mag"][i]) ** 2, float(dl_t[i])) for i in np.flatnonzero(has)]
    st_cols = [column(sf, sx[:, j], float(st_end[j])) for j in range(sx.shape[1]) if st_end[j] >= dl_t[has][0] - 1e-9] if has.any() else []
    tf_near = float(np.mean([c[0] for c in tf_cols])) if tf_cols else float("nan")
    st_near = float(np.mean([c[0] for c in st_cols])) if st_cols else float("nan")
    tf_low = float(np.nanmedian([c[2] for c in tf_cols])) if tf_cols else float("nan")
    st_low = float(np.nanmedian([c[2] for c in st_cols])) if st_cols else float("nan")
    tf_low_valid = float(np.nanmean([c[3] for c in tf_cols])) if tf_cols else float("nan")
    return Clutter(tf_cols, st_cols, tf_near, st_near, tf_low, st_low, tf_low_valid)


def spectrogram_figure(
    tf: dict[str, np.ndarray],
    interval_s: float,
    plain: tuple[np.ndarray, np.ndarray, np.ndarray],
    truth_t: np.ndarray,
    truth_f: np.ndarray,
    f_max_hz: float,
    plain_title: str = "plain spectrogram of the link-2 deflection",
) -> Figure:
    """The downloads' |H| in dB (each column drawn over the ``interval_s`` before its download; invalid bins
    blank) beside the ``plain`` spectrogram (drawn at each window's end), up to ``f_max_hz``, with the true first
    (white) and second (dashed) modes."""
    freqs = np.asarray(tf["freqs_hz"])
    dl_t = np.asarray(tf["sim_time_s"])
    sx, st_end, sf = plain
    fig = new_figure(12.0, 11.0)
    axes = fig.subplots(3, 2, sharex=True, sharey=True).ravel()
    m = freqs <= f_max_hz
    idx = np.flatnonzero(downloads_with_estimate(tf))
    edges_t = np.concatenate([[dl_t[idx[0]] - interval_s], dl_t[idx]])
    df = freqs[1] - freqs[0]
    edges_f = np.concatenate([freqs[m] - df / 2, [freqs[m][-1] + df / 2]])
    for ax, name in zip(axes[:5], TF_NAMES):
        mag = np.asarray(tf[f"{name}_mag"])[idx][:, m].T
        with np.errstate(divide="ignore"):
            db = np.where(mag > 0, 20 * np.log10(np.where(mag > 0, mag, 1.0)), np.nan)
        vmax = np.nanpercentile(db, 99.5) if np.isfinite(db).any() else 0.0
        pc = ax.pcolormesh(edges_t, edges_f, np.ma.masked_invalid(db), cmap="magma", vmin=vmax - 40, vmax=vmax, shading="flat")
        fig.colorbar(pc, ax=ax, pad=0.01, fraction=0.05, label="dB")
        ax.set_title(f"|{name}| (DSP downloads)", fontsize=9)
    ax = axes[5]
    ms = sf <= f_max_hz
    if sx.shape[1]:
        db = 10 * np.log10(np.maximum(sx[ms], 1e-30))
        vmax = np.percentile(db, 99.5)
        dt = st_end[1] - st_end[0] if st_end.size > 1 else 1.0
        te = np.concatenate([[st_end[0] - dt], st_end])
        dfs = sf[1] - sf[0]
        fe = np.concatenate([sf[ms] - dfs / 2, [sf[ms][-1] + dfs / 2]])
        pc = ax.pcolormesh(te, fe, db, cmap="magma", vmin=vmax - 50, vmax=vmax, shading="flat")
        fig.colorbar(pc, ax=ax, pad=0.01, fraction=0.05, label="dB (in²/Hz)")
    ax.set_title(plain_title, fontsize=9)
    for ax in axes:
        ax.plot(truth_t, truth_f[:, 0], color="w", lw=1.0)
        ax.plot(truth_t, truth_f[:, 1], color="w", lw=0.8, ls="--")
        ax.set_ylim(0, f_max_hz)
    for ax in axes[4:]:
        ax.set_xlabel("time (s)")
    for ax in axes[::2]:
        ax.set_ylabel("frequency (Hz)")
    return fig
