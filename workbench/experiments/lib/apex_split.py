"""The split of the resonant peak near the singular top of the workspace (thesis §2.2, §4.2.2), measured.

Near the singularity (θ2 small, the *apex* of a loop through the top of the
workspace) the arm behaves like an inverted double pendulum: the two modes
close in and the resonant peak splits in two, and the thesis finds the
estimate then favours the higher pole. Here:

* :func:`apex_samples`: the apex (θ2 in its lowest quantile) and where the
  identified pole sits there against the true modes;
* :func:`split_peaks`: which true modes one |H| shows (its peaks that stand
  out from the estimate's own noise peaks);
* :func:`apex_split`: per download whose window lies largely at the apex, the
  plant's own transfer functions over the window
  (:func:`~workbench.experiments.lib.windowed_plant_response.window_response`)
  against the identified ones, and which solve the DSP used at each mode;
* :func:`split_agreement`: the check over (truth, identified) pairs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
import scipy.signal as ss

from workbench.experiments.lib.identifier_replay import arx_memory_s, replay_arx_responses, replay_downloads
from workbench.experiments.lib.windowed_plant_response import WINDOW_POINTS, tf_magnitudes, window_response
from workbench.rig_record import RunRecord

__all__ = [
    "APEX_TABLE_HEADER",
    "SPLIT_AGREEMENT",
    "SPLIT_NAMES",
    "SPLIT_PROMINENCE_DB",
    "SPLIT_TOL_HZ",
    "ApexStats",
    "SplitAgreement",
    "apex_samples",
    "apex_download_rows",
    "apex_split",
    "describe_split",
    "split_agreement",
    "split_codes",
    "split_peaks",
]

SPLIT_TOL_HZ = 0.5
"""A download shows a mode when |H| has a peak (≥ SPLIT_PROMINENCE_DB) within this of the true frequency."""
SPLIT_PROMINENCE_DB = 2.0
SPLIT_AGREEMENT = 0.8
"""The split check: the identified |H| shows both modes in at least this share of the apex cases where the
plant's own |H| does, and invents a second mode in at most the rest of the cases where the plant's shows none."""
SPLIT_NAMES = ("Htot", "H11", "H12", "H21", "H22")


@dataclass(frozen=True)
class ApexStats:
    """The apex (θ2 in its lowest quantile) against the rest of the run."""

    apex_upper: float
    """Share of the apex samples with an estimate where the identified pole is nearer the true second mode."""
    away_upper: float
    """The same away from the apex."""
    split_ratio_apex: float
    """Median f2/f1 of the true modes at the apex."""
    split_ratio_else: float
    """The same away from the apex."""


def apex_samples(res: RunRecord, f_id: np.ndarray, quantile: float) -> tuple[np.ndarray, np.ndarray, ApexStats]:
    """θ2 at the controller's ticks, the apex (θ2 in its lowest ``quantile`` over the run) and where the
    identified pole ``f_id`` sits there: how often nearer the true second mode, and how close the true modes come."""
    t = res.t_s
    th2 = res.true_theta(t)[:, 1]
    apex = th2 <= np.quantile(th2, quantile)
    tr1, tr2 = res.true_mode_hz(t, 0), res.true_mode_hz(t, 1)
    est = np.isfinite(f_id)
    sel = apex & est
    nearer_upper = np.abs(f_id - tr2) < np.abs(f_id - tr1)
    apex_upper = float(np.mean(nearer_upper[sel])) if sel.any() else float("nan")
    away_upper = float(np.mean(nearer_upper[~apex & est])) if (~apex & est).any() else float("nan")
    split_ratio_apex = float(np.median((tr2 / tr1)[apex]))
    split_ratio_else = float(np.median((tr2 / tr1)[~apex]))
    return th2, apex, ApexStats(apex_upper, away_upper, split_ratio_apex, split_ratio_else)


def split_peaks(
    freqs: np.ndarray, mag: np.ndarray, f1: float, f2: float, tol: float = SPLIT_TOL_HZ, band_hz: tuple[float, float] = (1.0, 12.0)
) -> dict[str, Any]:
    """Which true modes one |H| shows (invalid = 0 bins set to the lowest valid level).

    Its peaks in ``band_hz`` (``scipy.signal.find_peaks``) with their prominences; the *noise level* is the largest
    prominence of a peak farther than ``tol`` from both ``f1`` and ``f2`` (what the estimate's scatter makes
    where there is no mode; 0 for a clean response). A mode is shown when a peak within ``tol`` of it is at
    least SPLIT_PROMINENCE_DB prominent and more prominent than the noise level: a peak that does not stand
    out from the estimate's own noise peaks says nothing about a mode, in either direction."""
    band = (freqs >= band_hz[0]) & (freqs <= band_hz[1])
    m = mag[band]
    ok = m > 0
    if not ok.any():
        return {"peaks_hz": [], "prominences_db": [], "noise_db": float("nan"), "near_f1": False, "near_f2": False, "both_modes": False}
    db = 20.0 * np.log10(np.where(ok, m, m[ok].min()))
    idx, props = ss.find_peaks(db, prominence=0.0)
    fp = freqs[band][idx]
    prom = np.asarray(props["prominences"], dtype=float)
    away = (np.abs(fp - f1) > tol) & (np.abs(fp - f2) > tol)
    noise = float(prom[away].max()) if away.any() else 0.0
    need = max(SPLIT_PROMINENCE_DB, noise)
    shown = prom >= need
    shown &= prom > noise
    near1 = bool(np.any(shown & (np.abs(fp - f1) <= tol)))
    near2 = bool(np.any(shown & (np.abs(fp - f2) <= tol)))
    keep = prom >= SPLIT_PROMINENCE_DB
    return {
        "peaks_hz": [float(x) for x in fp[keep]],
        "prominences_db": [float(x) for x in prom[keep]],
        "noise_db": noise,
        "near_f1": near1,
        "near_f2": near2,
        "both_modes": near1 and near2,
    }


class SplitAgreement(TypedDict):
    """:func:`split_agreement`: the identified transfer functions' peaks against the plant's own, at the apex."""

    truth_two: int
    """(download, transfer function) pairs where the plant's own |H| has both modes as peaks."""
    shown_both: int
    """Of those, how many the identified |H| shows both in."""
    truth_one: int
    """Pairs where the plant's own |H| has no peak at the second mode."""
    invented: int
    """Of those, how many the identified |H| has a peak at the second mode in (a second mode the truth does not show)."""
    passed: bool
    """``shown_both ≥ SPLIT_AGREEMENT · truth_two`` and ``invented ≤ (1 − SPLIT_AGREEMENT) · truth_one`` (vacuous parts hold)."""


def split_agreement(pairs: list[tuple[dict[str, Any], dict[str, Any]]], share: float | None = None) -> SplitAgreement:
    """The split check on (truth, identified) :func:`split_peaks` results: (i) where the truth shows both modes the
    identified estimate shows both, (ii) where the truth shows no second mode the estimate does not invent one;
    each in at least ``share`` (default ``SPLIT_AGREEMENT``) of its cases."""
    share = SPLIT_AGREEMENT if share is None else share
    two = [(t, e) for t, e in pairs if t["both_modes"]]
    one = [(t, e) for t, e in pairs if not t["near_f2"]]
    shown = sum(bool(e["both_modes"]) for _, e in two)
    invented = sum(bool(e["near_f2"]) for _, e in one)
    eps = 1e-9  # 0.8 · 5 must allow 4 of 5, not fall a rounding short
    ok = (shown >= share * len(two) - eps) and (invented <= (1.0 - share) * len(one) + eps)
    return {"truth_two": len(two), "shown_both": shown, "truth_one": len(one), "invented": invented, "passed": bool(ok)}


def split_codes(shown: dict[str, dict[str, Any]], truth: dict[str, dict[str, Any]] | None = None) -> str:
    """The modes each of ``SPLIT_NAMES`` shows, one digit a transfer function (2 both, 1 the first only, 0 neither);
    with ``truth``, a ``+`` for each second mode ``shown`` has and ``truth`` does not."""
    code = "".join("2" if shown[k]["both_modes"] else ("1" if shown[k]["near_f1"] else "0") for k in SPLIT_NAMES)
    if truth is not None:
        code += "".join("+" for k in SPLIT_NAMES if shown[k]["near_f2"] and not truth[k]["near_f2"])
    return code


def _solves(est: Any, freqs: np.ndarray, f1: float, f2: float, band: np.ndarray) -> dict[str, Any]:
    """Which solve the replayed DSP used at each true mode's bin (1: dominant direction, 2: full 2×2) and its share in ``band``."""
    if est is None:
        return {"replayed": False}
    mode = np.asarray(est.mode)
    k1, k2 = int(np.argmin(np.abs(freqs - f1))), int(np.argmin(np.abs(freqs - f2)))
    return {"replayed": True, "solve_at_f1": int(mode[k1]), "solve_at_f2": int(mode[k2]), "full_2x2_share_3_6hz": float(np.mean(mode[band] == 2))}


def apex_split(res: RunRecord, apex: np.ndarray, batch_size: int, window_share: float, *, fft_width: int, fs_hz: float) -> dict[str, Any]:
    """The split check's numbers for one run, per apex download (≥ ``window_share`` of its ``fft_width``-sample
    window at the apex): the plant's own transfer functions over the download's window (:func:`window_response`:
    the reference of the check) and at the median true configuration of the window's apex samples
    (``truth_at_apex``), in the run's payload state, and the downloaded ones (an ARX run: the replayed ARX
    model's own), each through :func:`split_peaks` for every name in ``SPLIT_NAMES``; the share of the 3–6 Hz bins
    solved; and, from the DSP replayed (:func:`replay_downloads`), which solve each true mode's bin used.
    :func:`split_agreement` over them (per name, and ``Hij`` over the four together) is the check."""
    from plant_emulator.model.modes import frequency_response

    t = res.t_s
    tf = res.tf
    if tf is None:
        return {"downloads": [], "payload": None, "agreement": {}, "mean_valid_3_6hz": float("nan")}
    freqs = np.asarray(tf["freqs_hz"])
    dl_t = np.asarray(tf["sim_time_s"])
    tr1, tr2 = res.true_mode_hz(t, 0), res.true_mode_hz(t, 1)
    theta = res.true_theta(t)
    payload = bool(np.median(np.asarray(res.truth_columns["payload_attached"], dtype=float)) > 0.5)
    is_arx = res.settings["dsp"].get("identifier") == "arx"
    replayed = {} if is_arx else replay_downloads(res, batch_size)
    arx_h: dict[int, np.ndarray] = {}
    memory_s: float | None = None
    if is_arx:  # the identified transfer functions are the ARX model's (its downloads are the ETFE's)
        memory_s = arx_memory_s(fs_hz)
        arx_h = replay_arx_responses(res, batch_size, {int(round(ts / (batch_size * res.sample_period_s))) - 1: i for i, ts in enumerate(dl_t)}, freqs)
    rows = []
    for i in range(dl_t.size):
        mag = np.asarray(tf["Htot_mag"][i], dtype=float)
        if not np.any(mag > 0):
            continue
        w = (t > dl_t[i] - fft_width / fs_hz) & (t <= dl_t[i])
        at_apex = w & apex[: t.size]
        share = float(at_apex.sum() / max(1, w.sum()))
        if share < window_share:
            continue
        f1_a, f2_a = float(np.median(tr1[at_apex])), float(np.median(tr2[at_apex]))
        band = (freqs >= 3.0) & (freqs <= 6.0)
        th = np.median(theta[at_apex], axis=0)
        true_h = frequency_response(float(th[0]), float(th[1]), freqs, payload=payload)  # (n, input i, output j)
        win_h, tk, wk = window_response(res, float(dl_t[i]), freqs, payload, memory_s=memory_s, fft_width=fft_width, fs_hz=fs_hz)
        # the modes the window's data hold: the true frequencies averaged with the same weights
        f1_i = float(np.average(res.true_mode_hz(tk, 0), weights=wk))
        f2_i = float(np.average(res.true_mode_hz(tk, 1), weights=wk))
        if is_arx:
            h = arx_h[i] if i in arx_h else np.zeros((4, freqs.size), dtype=complex)
            ident_mags = tf_magnitudes(h.T.reshape(freqs.size, 2, 2))
        else:
            ident_mags = {k: np.asarray(tf[f"{k}_mag"][i], dtype=float) for k in SPLIT_NAMES}
        row: dict[str, Any] = {
            "t_s": float(dl_t[i]),
            "apex_share": share,
            "f1_hz": f1_i,
            "f2_hz": f2_i,
            "f1_spread_hz": float(np.ptp(tr1[w])),
            "f2_spread_hz": float(np.ptp(tr2[w])),
            "valid_3_6hz": float(np.mean(mag[band] > 0)),
            "f1_apex_hz": f1_a,
            "f2_apex_hz": f2_a,
            "truth_at_apex": {k: split_peaks(freqs, v, f1_a, f2_a) for k, v in tf_magnitudes(true_h).items()},
            "truth": {k: split_peaks(freqs, v, f1_i, f2_i) for k, v in tf_magnitudes(win_h).items()},
            "identified": {k: split_peaks(freqs, v, f1_i, f2_i) for k, v in ident_mags.items()},
        }
        row.update(_solves(replayed.get(i), freqs, f1_i, f2_i, band))
        rows.append(row)
    agreement: dict[str, SplitAgreement] = {k: split_agreement([(r["truth"][k], r["identified"][k]) for r in rows]) for k in SPLIT_NAMES}
    agreement["Hij"] = split_agreement([(r["truth"][k], r["identified"][k]) for r in rows for k in SPLIT_NAMES[1:]])
    return {
        "downloads": rows,
        "payload": payload,
        "agreement": agreement,
        "replayed_downloads": int(sum(r["replayed"] for r in rows)),
        "mean_valid_3_6hz": float(np.mean([r["valid_3_6hz"] for r in rows])) if rows else float("nan"),
    }


APEX_TABLE_HEADER = [
    "run",
    "download (s)",
    "true f1 (Hz)",
    "true f2 (Hz)",
    "f1 / f2 spread in the window (Hz)",
    "plant at the apex configuration: modes shown in H_tot, H11, H12, H21, H22",
    "plant over the window (the reference)",
    "identified (+: a second mode the plant's does not show)",
    "solve at f1 / f2",
    "3–6 Hz bins by the full 2×2 (%)",
    "3–6 Hz bins solved (%)",
]
"""The columns of :func:`apex_download_rows`."""


def apex_download_rows(run: str, split: dict[str, Any]) -> list[list[Any]]:
    """One table row per apex download of an :func:`apex_split` result (columns: :data:`APEX_TABLE_HEADER`):
    the modes the plant shows at the apex configuration and over the window, and the identified ones
    (:func:`split_codes`), the solve at each mode and the share of the 3–6 Hz bins solved."""
    return [
        [
            run,
            r["t_s"],
            r["f1_hz"],
            r["f2_hz"],
            f"{r['f1_spread_hz']:.2f} / {r['f2_spread_hz']:.2f}",
            split_codes(r["truth_at_apex"]),
            split_codes(r["truth"]),
            split_codes(r["identified"], r["truth"]),
            f"{r.get('solve_at_f1', '–')} / {r.get('solve_at_f2', '–')}",
            100 * r.get("full_2x2_share_3_6hz", float("nan")),
            100 * r["valid_3_6hz"],
        ]
        for r in split["downloads"]
    ]


def describe_split(rows: list[dict[str, Any]], window_share: float, *, fft_width: int, fs_hz: float) -> str:
    """How :func:`apex_split` measures the split and what the check asks, with the numbers of its apex download
    ``rows`` (the thesis-setting ETFE's, both payload states): the spread of the true modes within a window and
    the number of noise peaks an estimate has (for a report's text)."""
    spread1 = max((r["f1_spread_hz"] for r in rows), default=float("nan"))
    spread2 = max((r["f2_spread_hz"] for r in rows), default=float("nan"))
    n_peaks = [len(r["identified"]["Htot"]["peaks_hz"]) for r in rows]
    return (
        "Each apex download (≥ "
        f"{window_share:.0%} of its {fft_width / fs_hz:.2f}-s window at the apex) is compared with the plant's own transfer functions "
        "(`plant_emulator.model.modes.frequency_response`, in the run's payload state; H_tot the mean of the four, as the DSP forms it) as the "
        f"download's data hold them: averaged over {WINDOW_POINTS} true configurations across its window, weighted by the squared Hann window "
        "times the valve commands' local power in 2–10 Hz (the weight each instant has in the averaged cross-spectra). The configuration moves "
        f"within a window (over these apex windows the true f1 spans up to {spread1:.2f} Hz and f2 up to {spread2:.2f} Hz: the spread column), so the "
        "plant at the single apex configuration (also listed) is not what a window-long estimate can see. A transfer function *shows* a mode "
        f"when its magnitude has a peak within {SPLIT_TOL_HZ:g} Hz of the mode's frequency (its true frequency averaged with the same weights) "
        f"that is ≥ {SPLIT_PROMINENCE_DB:g} dB prominent and more prominent than every peak in 1–12 Hz away from both modes (the estimate's own "
        f"noise peaks: the thesis-setting ETFE's apex downloads have {min(n_peaks, default=0)}–{max(n_peaks, default=0)} peaks of ≥ "
        f"{SPLIT_PROMINENCE_DB:g} dB in that band, so a peak "
        f"near a mode is no evidence unless it stands out from them). The tolerance: the ETFE's bins are {fs_hz / fft_width:.3f} Hz, its "
        f"Hann main lobe ±{2 * fs_hz / fft_width:.2f} Hz, and it is smoothed over {17 * fs_hz / fft_width:.2f} Hz (17 bins), while the true modes "
        "move within the window (the spread column). **Check** (thesis-setting ETFE, the DSP's downloads): (i) where the plant's |H| shows "
        f"both modes the identified |H| shows both, and (ii) where the plant's shows no second mode the identified one shows none, each in ≥ "
        f"{SPLIT_AGREEMENT:.0%} of its cases, for H_tot and for the four H_ij together, in both payload states. The DSP is replayed from the "
        "record (its inputs and outputs sample for sample; the replay reproduces each download's |H_tot|) to read which solve each mode's bin "
        "used: 1 = the dominant input direction (collinear inputs), 2 = the full 2×2. The ARX rows use the ARX model's own transfer functions "
        "(replayed), against the plant over its 1-s memory (exponential weights instead of the Hann window)."
    )
