"""``verify``: the thesis's implementation and algorithm checks of the on-line identifier (§4.1.1, §4.1.2).

The rig runs PI control along the inspection loop (30 s; ``--quick`` 12.6 s)
with the DSP at the thesis's settings (N = 2048, α = 0.1, l = 20, 17-bin
order-2 smoothing) and downloads its transfer-function estimates.  The run
record holds exactly what went to the DSP: the D/A commands ``u1_v``,
``u2_v`` (inputs) and the measured deflections ``defl1_in``, ``defl2_in``
(outputs), one row per tick.

§4.1.1: every download with an estimate against its recomputation from the
record with SciPy only (:mod:`workbench.experiments.lib.dsp_tf_recompute`),
magnitudes compared on every bin the DSP reports valid; the download's time
stamp must be a batch end.  §4.1.2: a Blackman–Tukey estimate of the same
data (:mod:`workbench.experiments.lib.blackman_tukey`) over the stretch the
on-line estimate drew on (its last snapshot's N samples and ``BT_EXTRA``
before them), with a lag window of the on-line estimate's bandwidth and one
of N/2 lags: their poles and roughness
(:mod:`workbench.experiments.lib.spectrum_features`).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import scipy.signal as ss

from workbench.campaign.rigs import in_context
from workbench.experiments.analysis import THESIS_BATCH_SIZE
from workbench.experiments.framework import ExperimentContext, experiment
from workbench.experiments.lib.blackman_tukey import blackman_tukey, bt_bandwidth_bins, matched_max_lag, online_bandwidth_bins
from workbench.experiments.lib.dsp_tf_recompute import PAIRS, TF_NAMES, averaged_spectra, batch_ends, named_tfs
from workbench.experiments.lib.spectrum_features import dominant_peak_hz, magnitude_agreement, roughness_db
from workbench.experiments.lib.tf_downloads import TfDownloads
from workbench.experiments.report import Report, new_figure
from workbench.hil import HilRig, RigRunError, RigSpec, RunRecord

FS_HZ = 200.0
FFT_WIDTH = 2048
ALPHA = 0.1
SMOOTHING = (17, 2)
"""Savitzky–Golay window (bins) and order of the DSP's smoother."""
BT_ENSEMBLE = 1024
BT_HOP = 64
BT_EXTRA = 200
PEAK_BAND_HZ = (1.0, 12.0)
ROUGH_BAND_HZ = (1.0, 20.0)
POLE_TOLERANCE_HZ = 0.5


class DspIo(NamedTuple):
    """What went to the DSP, a column per tick (rows u1, u2, y1, y2), and the last tick of every batch."""

    channels: np.ndarray
    ends: np.ndarray


def _stretch_start(end_tick: int) -> int:
    """First tick of the stretch the on-line estimate ending at ``end_tick`` drew on, and ``BT_EXTRA`` before it."""
    return max(0, end_tick + 1 - FFT_WIDTH - BT_EXTRA)


class LastEstimates(NamedTuple):
    """The last download's off-line recomputation, Blackman–Tukey estimates (by lag window) and unsmoothed solve (complex)."""

    offline: dict[str, np.ndarray]
    bt: dict[str, dict[str, np.ndarray]]
    unsmoothed: dict[str, np.ndarray]


@experiment(
    "verify",
    section="§4.1.1, §4.1.2",
    description="On-line TF estimates of the DSP against an independent SciPy recomputation (csd/welch, same window and averaging) and a Blackman-Tukey estimate",
    needs_rig=True,
)
def run(ctx: ExperimentContext) -> Report:
    rep = ctx.report("Verification of the on-line identifier: implementation and algorithm checks")
    duration, download = (12.6, 2500) if ctx.quick else (30.0, 1000)
    spec = RigSpec(
        "verify_pi",
        controller={"duration_s": duration, "batch_size": THESIS_BATCH_SIZE, "tf_download_samples": download, "oatf_mode": "off"},
        plant={"seed": int(ctx.rng("plant-seed").integers(0, 2**31 - 1))},
        dsp={"batch_size": THESIS_BATCH_SIZE, "fft_width": FFT_WIDTH, "alpha": ALPHA, "smoothing": {"window": SMOOTHING[0], "order": SMOOTHING[1]}},
        label="PI only, inspection loop, 5 in/s",
    )
    with HilRig.from_spec(in_context(ctx, spec, ctx.quick)) as rig:
        res = rig.run()
    if res.error:
        raise RigRunError(f"run {res.name!r} ({res.layout}) ended with a fault: {res.error}")
    dl = TfDownloads.of(res)
    channels = np.vstack([res.columns[c] for c in ("u1_v", "u2_v", "defl1_in", "defl2_in")]).astype(float)
    io = DspIo(channels, batch_ends(res.columns["irq_applied"], THESIS_BATCH_SIZE, channels.shape[1]))

    impl, offline, spectra_at = _implementation_check(dl, io)
    algo, bt_last, raw_last = _algorithm_check(dl, io, impl, spectra_at, res)
    last = LastEstimates(offline, bt_last, raw_last)
    _results(rep, res, dl, io, download, impl, algo, last)
    _run_and_implementation(rep, res, dl, io, duration, download, impl)
    _implementation_figures(rep, dl, last, algo["downloads"][-1])
    _algorithm_section(rep, algo)
    _checks_and_thesis(rep, dl, impl, algo)
    rep.attach(res.output(".npz"), "controller run record (inputs u1_v, u2_v and outputs defl1_in, defl2_in sent to the DSP)")
    rep.attach(res.output(".tf.npz"), "the DSP's transfer-function downloads")
    rep.attach(res.output(".truth.npz"), "plant ground truth (modal frequencies)")
    return rep


def _implementation_check(dl: TfDownloads, io: DspIo) -> tuple[list[dict[str, Any]], dict[str, np.ndarray], dict[int, np.ndarray]]:
    """§4.1.1: every download with data against the off-line recomputation; the last one's estimates, the averaged spectra of each."""
    impl: list[dict[str, Any]] = []
    spectra_at: dict[int, np.ndarray] = {}
    off: dict[str, np.ndarray] = {}
    for i in dl.have:
        end_tick = int(round(dl.times[i] * FS_HZ)) - 1
        spectra, f_off, n_snap = averaged_spectra(io.channels, io.ends[io.ends <= end_tick], FFT_WIDTH, ALPHA, FS_HZ)
        spectra_at[i] = spectra
        off = named_tfs(spectra, SMOOTHING)
        row: dict[str, Any] = {
            "sim_time_s": float(dl.times[i]),
            "end_tick": end_tick,
            "end_is_a_batch_end": bool(np.any(io.ends == end_tick)),
            "snapshots": n_snap,
            "grid_equal": bool(np.allclose(f_off, dl.freqs, rtol=0, atol=1e-12)),
        }
        for name in TF_NAMES:
            on = dl.magnitude(i, name)
            row[name] = {
                **magnitude_agreement(dl.freqs, on, off[name], (0.5, 40.0)),
                "peak_online_hz": dominant_peak_hz(dl.freqs, on, on > 0, PEAK_BAND_HZ),
                "peak_offline_hz": dominant_peak_hz(dl.freqs, np.abs(off[name]), on > 0, PEAK_BAND_HZ),
            }
        impl.append(row)
    return impl, off, spectra_at


def _algorithm_check(
    dl: TfDownloads, io: DspIo, impl: list[dict[str, Any]], spectra_at: dict[int, np.ndarray], res: RunRecord
) -> tuple[dict[str, Any], dict[str, dict[str, np.ndarray]], dict[str, np.ndarray]]:
    """§4.1.2: Blackman–Tukey at every download with a matched and a half-N lag window; the last one's BT and unsmoothed estimates."""
    b_online = online_bandwidth_bins(FFT_WIDTH, *SMOOTHING)
    lag_sets = {"matched": matched_max_lag(b_online, FFT_WIDTH), "half_N": FFT_WIDTH // 2}
    algo: dict[str, Any] = {
        "online_bandwidth_bins": b_online,
        "lag_windows": {
            k: {"max_lag": m, "ensemble_samples": max(BT_ENSEMBLE, 2 * m), "bandwidth_bins": bt_bandwidth_bins(m, FFT_WIDTH)} for k, m in lag_sets.items()
        },
        "hop_samples": BT_HOP,
        "downloads": [],
    }
    ests: dict[str, dict[str, np.ndarray]] = {}
    raws: dict[str, np.ndarray] = {}
    for r in impl:
        i = int(np.flatnonzero(np.isclose(dl.times, r["sim_time_s"]))[0])
        start, stop = _stretch_start(r["end_tick"]), r["end_tick"] + 1
        t_span = np.arange(start, stop) / FS_HZ
        true1, true2 = res.true_mode_hz(t_span, 0), res.true_mode_hz(t_span, 1)
        entry: dict[str, Any] = {
            "sim_time_s": r["sim_time_s"],
            "stretch_s": [start / FS_HZ, stop / FS_HZ],
            "true_f1_hz": [float(true1.min()), float(true1.mean()), float(true1.max())],
            "true_f2_hz": [float(true2.min()), float(true2.mean()), float(true2.max())],
        }
        for key, m in lag_sets.items():
            spectra_bt, entry[f"ensembles_{key}"] = blackman_tukey(io.channels, PAIRS, start, stop, max(BT_ENSEMBLE, 2 * m), BT_HOP, m, FFT_WIDTH)
            ests[key] = named_tfs(spectra_bt)
        raws = named_tfs(spectra_at[i])
        for name in TF_NAMES:
            on = dl.magnitude(i, name)
            valid = on > 0
            dom_on = dominant_peak_hz(dl.freqs, on, valid, PEAK_BAND_HZ)
            dom_bt = dominant_peak_hz(dl.freqs, np.abs(ests["matched"][name]), valid, PEAK_BAND_HZ)
            mags = {"online": on, "bt_matched": np.abs(ests["matched"][name]), "bt_half_N": np.abs(ests["half_N"][name]), "unsmoothed": np.abs(raws[name])}
            rough = {k: roughness_db(dl.freqs, mag, valid, ROUGH_BAND_HZ) for k, mag in mags.items()}
            entry[name] = {"dominant_online_hz": dom_on, "dominant_bt_hz": dom_bt, "abs_diff_hz": abs(dom_on - dom_bt), "roughness_db": rough}
        algo["downloads"].append(entry)
    return algo, dict(ests), raws


def _pairs(algo: dict[str, Any], name: str | None = None) -> list[tuple[dict[str, Any], str, dict[str, Any]]]:
    """(download entry, estimate name, its comparison) over every download and estimate (or one estimate)."""
    return [(e, n, e[n]) for e in algo["downloads"] for n in TF_NAMES if name in (None, n)]


def _smoother(algo: dict[str, Any], than: str, name: str | None = None) -> list[bool]:
    """Per download and estimate (or one estimate): is the on-line estimate less rough than ``than`` (a ``roughness_db`` key)?"""
    return [c["roughness_db"]["online"] < c["roughness_db"][than] for _, _, c in _pairs(algo, name)]


def _results(
    rep: Report, res: RunRecord, dl: TfDownloads, io: DspIo, download: int, impl: list[dict[str, Any]], algo: dict[str, Any], last: LastEstimates
) -> None:
    """Everything numeric the report keeps."""
    diffs = [c["abs_diff_hz"] for _, _, c in _pairs(algo) if math.isfinite(c["abs_diff_hz"])]
    htot_diffs = [c["abs_diff_hz"] for _, _, c in _pairs(algo, "Htot") if math.isfinite(c["abs_diff_hz"])]
    smoother = {k: _smoother(algo, f"bt_{k}") for k in ("half_N", "matched")}
    last_end, last_i = impl[-1]["end_tick"], dl.have[-1]
    u = io.channels[:2, _stretch_start(last_end) : last_end + 1]
    coh_f, coh = ss.coherence(u[0], u[1], fs=FS_HZ, nperseg=512)
    valid_last = dl.valid(last_i)
    above = valid_last & (dl.freqs > 0.3)
    last_entry = algo["downloads"][-1]
    rep.results = {
        "run": res.run_facts(),
        "settings": {"fft_width": FFT_WIDTH, "alpha": ALPHA, "batch_size": THESIS_BATCH_SIZE, "smoothing": list(SMOOTHING), "tf_download_samples": download},
        "batches": {"reconstructed": int(io.ends.size), "sent_by_controller": res.counters.get("batches_sent")},
        "implementation": impl,
        "algorithm": algo,
        "last_download": {
            "sim_time_s": float(dl.times[last_i]),
            "lowest_valid_hz": float(dl.freqs[above].min()) if np.any(above) else float("nan"),
            "invalid_bins_below_20hz": int(np.count_nonzero((~valid_last) & (dl.freqs < 20.0) & (dl.freqs > 0))),
            "identified_f1_hz": float(res.columns["f_id_hz"][min(last_end + 1, io.channels.shape[1] - 1)]),
            "true_f1_hz": last_entry["true_f1_hz"],
            "true_f2_hz": last_entry["true_f2_hz"],
            "input_correlation": float(np.corrcoef(u)[0, 1]),
            "input_coherence_max_0.5_20hz": float(coh[(coh_f > 0.5) & (coh_f < 20)].max()),
        },
        "spectra_last": {
            "freqs_hz": dl.freqs.tolist(),
            **{f"{n}_online": dl.magnitude(last_i, n).tolist() for n in TF_NAMES},
            **{f"{n}_offline": np.abs(last.offline[n]).tolist() for n in TF_NAMES},
            **{f"{n}_unsmoothed": np.abs(last.unsmoothed[n]).tolist() for n in TF_NAMES},
            **{f"{n}_bt_{k}": np.abs(last.bt[k][n]).tolist() for n in TF_NAMES for k in last.bt},
        },
        "summary": {
            "worst_median_rel_diff": max(r[n]["median_rel_diff"] for r in impl for n in TF_NAMES),
            "worst_max_rel_diff": max(r[n]["max_rel_diff"] for r in impl for n in TF_NAMES),
            "median_abs_peak_diff_hz": float(np.median(diffs)) if diffs else float("nan"),
            "median_abs_peak_diff_htot_hz": float(np.median(htot_diffs)) if htot_diffs else float("nan"),
            "online_smoother_than_bt_half_N": f"{sum(smoother['half_N'])}/{len(smoother['half_N'])}",
            "online_smoother_than_bt_matched": f"{sum(smoother['matched'])}/{len(smoother['matched'])}",
        },
    }


def _run_and_implementation(rep: Report, res: RunRecord, dl: TfDownloads, io: DspIo, duration: float, download: int, impl: list[dict[str, Any]]) -> None:
    """The run and the implementation check's table."""
    rep.heading("Run")
    rep.text(
        f"PI control alone along the inspection loop at 5 in/s for {duration:g} s simulated "
        f"({'three processes, ' if res.layout == 'three processes' else 'one process, '}{res.clock}, {res.wall_time_s:.1f} s wall), "
        f"DSP at N = {FFT_WIDTH}, α = {ALPHA}, l = {THESIS_BATCH_SIZE}, Savitzky–Golay {SMOOTHING[0]} bins order {SMOOTHING[1]}; "
        f"transfer functions downloaded every {download} samples ({download / FS_HZ:g} s): {len(dl.have)} of {dl.times.size} downloads carry an estimate "
        f"(the identifier waits for a full history, {FFT_WIDTH / FS_HZ:.2f} s). "
        f"Batches: {io.ends.size} reconstructed from the record's interrupt ticks, {rep.results['batches']['sent_by_controller'] or '?'} sent by the controller."
    )
    rep.heading("Implementation check (§4.1.1)")
    rep.text(
        "Every download with an estimate, recomputed from the run record with `scipy.signal.csd`/`welch` over the N samples ending "
        "at each batch the DSP had processed (one segment, periodic Hann, `detrend='constant'`, density scaling), averaged with "
        f"weights (1 − α)^(K−k), the corrected 2×2 solve, `savgol_filter({SMOOTHING[0]}, {SMOOTHING[1]}, mode='interp')` on the real and "
        "imaginary parts, H_tot the mean of the four (see the module doc). Relative magnitude differences on the bins the DSP reports valid:"
    )
    keys = ("valid_bins", "median_rel_diff", "p99_rel_diff", "max_rel_diff", "peak_online_hz", "peak_offline_hz")
    rows = [[r["sim_time_s"], n, *(r[n][k] for k in keys), "yes" if r["end_is_a_batch_end"] else "**no**", r["snapshots"]] for r in impl for n in TF_NAMES]
    rep.table(
        ["download (s)", "estimate", "valid bins", "median rel. diff", "99th pct", "max", "peak on-line (Hz)", "peak off-line (Hz)"]
        + ["time stamp = a batch end", "snapshots averaged"],
        rows,
        caption=f"On-line (DSP download) against off-line (SciPy) magnitudes; peaks: largest |H| in {PEAK_BAND_HZ[0]:g}–{PEAK_BAND_HZ[1]:g} Hz on valid bins",
        digits=3,
    )


def _implementation_figures(rep: Report, dl: TfDownloads, est: LastEstimates, last: dict[str, Any]) -> None:
    """The spectra and the relative difference of the last download."""
    off, bt, raws = est
    i, ld = dl.have[-1], rep.results["last_download"]
    freqs, valid = dl.freqs, dl.valid(i)
    fig = new_figure(11.0, 11.0)
    axes = fig.subplots(5, 1, sharex=True)
    m = freqs <= 20.0
    for ax, name in zip(axes, TF_NAMES):
        on, raw = dl.magnitude(i, name), np.abs(raws[name])
        ax.axvspan(last["true_f1_hz"][0], last["true_f1_hz"][2], color="0.85", lw=0)
        ax.axvspan(last["true_f2_hz"][0], last["true_f2_hz"][2], color="mistyrose", lw=0)
        ax.semilogy(freqs[m], np.where(raw[m] > 0, raw[m], np.nan), color="0.6", lw=0.6, label="unsmoothed solve")
        ax.semilogy(freqs[m], np.abs(bt["half_N"][name][m]), color="tab:olive", lw=0.6, label="Blackman–Tukey, M = N/2")
        ax.semilogy(freqs[m], np.abs(bt["matched"][name][m]), color="tab:green", lw=1.2, label="Blackman–Tukey, matched bandwidth")
        ax.semilogy(freqs[m], np.where(on[m] > 0, on[m], np.nan), color="tab:blue", lw=2.4, label="on-line (DSP)")
        ax.semilogy(freqs[m], np.where(valid[m], np.abs(off[name][m]), np.nan), color="k", lw=0.8, ls=(0, (2, 2)), label="off-line (SciPy)")
        if ((~valid) & m).any():
            lo, hi = ax.get_ylim()
            ax.fill_between(freqs[m], lo, hi, where=(~valid)[m], color="none", hatch="//", edgecolor="0.7", lw=0)
            ax.set_ylim(lo, hi)
        ax.set_ylabel(f"|{name}|")
        ax.grid(True, lw=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=4, loc="upper right")
    axes[-1].set(xlabel="frequency (Hz)", xlim=(0, 20))
    rep.figure(
        fig,
        "verify_tf.png",
        f"Last download ({dl.times[i]:g} s): the DSP's smoothed estimates, the SciPy recomputation (black dashes, on top of them), the unsmoothed solve, the Blackman–Tukey estimates (bandwidth-matched and M = N/2); grey band: true first-mode range over the data, red: second mode; hatched: bins the DSP reports invalid.",
    )
    fig = new_figure(9.0, 3.8)
    ax = fig.add_subplot(1, 1, 1)
    for name in TF_NAMES:
        on, v = dl.magnitude(i, name), dl.valid(i, name)
        ax.semilogy(freqs[v], np.maximum(np.abs(np.abs(off[name][v]) - on[v]) / on[v], 1e-18), ".", ms=2, label=name)
    ax.set(xlabel="frequency (Hz)", ylabel="relative magnitude difference", ylim=(1e-18, 1e-6))
    ax.grid(True, lw=0.3, which="both")
    ax.legend(fontsize=7, ncol=5)
    rep.figure(fig, "verify_difference.png", "Relative difference |off-line − on-line| / on-line of the magnitudes at the last download, valid bins.")
    rep.text(
        f"In the last download the DSP marks {ld['invalid_bins_below_20hz']} bins below 20 Hz invalid (zero); the lowest valid bin above 0.3 Hz is "
        f"{ld['lowest_valid_hz']:.2f} Hz. Invalid bins are where the two inputs are too nearly collinear for the 2×2 solve (normalised determinant "
        f"of the input spectra below the identifier's threshold) and their smoothing neighbours: over the data span the valve commands "
        f"correlate at {ld['input_correlation']:.2f} and their coherence reaches {ld['input_coherence_max_0.5_20hz']:.4f} "
        "(the thesis: correlation 0.4 to 0.9)."
    )


def _algorithm_section(rep: Report, algo: dict[str, Any]) -> None:
    """The algorithm check's text and tables."""
    rep.heading("Algorithm check (§4.1.2)")
    lw = algo["lag_windows"]
    rep.text(
        f"Blackman–Tukey estimates of the same data at every download: ensembles evenly spaced every {BT_HOP} samples over the N samples of "
        f"the last snapshot and {BT_EXTRA} before them (about 1/α batches), biased auto/cross-correlations, a Tukey–Hanning lag window, "
        "evaluated on the DSP's bins, averaged over the ensembles, the same 2×2 solve. Two lag windows: "
        f"**matched**, M = {lw['matched']['max_lag']} lags ({lw['matched']['ensemble_samples']}-sample ensembles), whose equivalent bandwidth "
        f"({lw['matched']['bandwidth_bins']:.1f} bins) equals the on-line estimate's (Hann periodogram followed by the {SMOOTHING[0]}-bin "
        f"Savitzky–Golay smoother: {algo['online_bandwidth_bins']:.1f} bins); and **M = N/2** = {lw['half_N']['max_lag']} ({lw['half_N']['ensemble_samples']}-sample "
        f"ensembles, {lw['half_N']['bandwidth_bins']:.1f} bins), the nominal resolution of the N-point FFT. "
        f"Poles: the largest |H| in {PEAK_BAND_HZ[0]:g}–{PEAK_BAND_HZ[1]:g} Hz on the bins the on-line estimate is valid. "
        f"Roughness: RMS second difference of 20 log10|H| across bins, {ROUGH_BAND_HZ[0]:g}–{ROUGH_BAND_HZ[1]:g} Hz, valid bins (lower is smoother)."
    )
    rep.table(
        ["download (s)", "estimate", "pole on-line (Hz)", "pole BT matched (Hz)", "|Δ| (Hz)", "true 1st mode (Hz)", "true 2nd mode (Hz)"],
        [
            [e["sim_time_s"], n, c["dominant_online_hz"], c["dominant_bt_hz"], c["abs_diff_hz"]]
            + [f"{e[k][0]:.2f}–{e[k][2]:.2f}" for k in ("true_f1_hz", "true_f2_hz")]
            for e, n, c in _pairs(algo)
        ],
        caption="Dominant pole of each estimate; true modal frequencies over the data span (min–max)",
        digits=3,
    )
    rep.table(
        ["download (s)", "estimate", "on-line", "BT matched", "BT M = N/2", "unsmoothed solve"],
        [[e["sim_time_s"], n, *c["roughness_db"].values()] for e, n, c in _pairs(algo)],
        caption="Roughness (dB, RMS second difference across bins)",
        digits=3,
    )


def _checks_and_thesis(rep: Report, dl: TfDownloads, impl: list[dict[str, Any]], algo: dict[str, Any]) -> None:
    """The pass/fail checks and the comparison with the thesis."""
    summ = rep.results["summary"]
    worst_median, worst_max = summ["worst_median_rel_diff"], summ["worst_max_rel_diff"]
    exact = worst_median < 1e-9 and worst_max < 1e-6
    smoother_half_n, smoother_matched = _smoother(algo, "bt_half_N"), _smoother(algo, "bt_matched")
    frac_half_n = sum(smoother_half_n) / len(smoother_half_n) if smoother_half_n else math.nan
    rep.check_every(
        "every download's time stamp is a reconstructed batch end", [r["end_is_a_batch_end"] for r in impl], ", ".join(f"{r['sim_time_s']:g} s" for r in impl)
    )
    rep.check(
        "on-line and off-line magnitudes agree (median rel. diff < 1e-9, max < 1e-6)",
        exact and bool(impl),
        f"worst median {worst_median:.1e}, worst max {worst_max:.1e} over {len(impl)} downloads",
    )
    rep.check_every(
        "the same dominant peak on-line and off-line",
        [
            math.isclose(r[n]["peak_online_hz"], r[n]["peak_offline_hz"]) or (math.isnan(r[n]["peak_online_hz"]) and math.isnan(r[n]["peak_offline_hz"]))
            for r in impl
            for n in TF_NAMES
        ],
        "transfer functions of every download",
    )
    rep.check_every(
        "most valid bins (> 50 %) in every download",
        [r["Htot"]["valid_bins"] > 0.5 * dl.freqs.size for r in impl],
        ", ".join(str(r["Htot"]["valid_bins"]) for r in impl) + f" of {dl.freqs.size}",
    )
    rep.check_every(
        "the on-line estimate is smoother than Blackman–Tukey at the FFT's resolution (M = N/2): H_tot at every download, ≥ 80 % of all estimates",
        _smoother(algo, "bt_half_N", "Htot"),
        f"all estimates {sum(smoother_half_n)} of {len(smoother_half_n)}",
        also=frac_half_n >= 0.8,
    )
    rep.check_every("smoothing lowers the roughness of the solve (on-line < unsmoothed), every download and estimate", _smoother(algo, "unsmoothed"))
    rep.thesis(
        "§4.1.1: the DSP's FFT, spectra and transfer functions are virtually identical to an independent off-line implementation, apart from rounding in the noise floor.",
        f"{len(impl)} download(s) × 5 estimates: median relative difference ≤ {worst_median:.1e}, largest {worst_max:.1e} (double precision; the C40 computed in single).",
        exact,
    )
    pole_diff, n_diffs = summ["median_abs_peak_diff_hz"], sum(math.isfinite(c["abs_diff_hz"]) for _, _, c in _pairs(algo))
    rep.thesis(
        "§4.1.2: a correlation-based (Blackman–Tukey) analysis of the same data on evenly spaced ensembles finds the same pole locations.",
        f"Dominant poles differ by {pole_diff:.2f} Hz (median over {n_diffs} download × estimate pairs; H_tot {summ['median_abs_peak_diff_htot_hz']:.2f} Hz), "
        f"bin width {FS_HZ / FFT_WIDTH:.3f} Hz; the true first mode moves over the data span (see the table), and the exponential average weights "
        "the data differently from the ensembles' equal weights.",
        True if pole_diff <= POLE_TOLERANCE_HZ else ("partly" if pole_diff <= 2 * POLE_TOLERANCE_HZ else False),
    )
    rep.thesis(
        "§4.1.2: the on-line estimate is smoother.",
        f"Than Blackman–Tukey at the FFT's resolution (M = N/2): {sum(smoother_half_n)} of {len(smoother_half_n)}; at equal equivalent bandwidth "
        f"(M = {algo['lag_windows']['matched']['max_lag']}): {sum(smoother_matched)} of {len(smoother_matched)} (the lag window smooths the spectra before the 2×2 solve, the on-line "
        "smoother smooths the solved transfer functions).",
        True if frac_half_n >= 0.8 and sum(smoother_matched) >= 0.5 * len(smoother_matched) else ("partly" if frac_half_n >= 0.8 else False),
    )
