"""``vrm``: the Variable Residue Method on a synthetic single-mode FRF (thesis App. C, Figs. C.1-C.6).

The FRF is the receptance of one viscous mode, ``H(f) = w_n^2 / (w_n^2 - w^2 +
2 j zeta w_n w)``, 4.4 Hz, ``zeta = 0.09``, on the identifier's grid (2048
points at 200 Hz: bins ``k fs / N``).  Noise is complex, circular and
proportional to the FRF at each bin: ``H + eps |H| n`` with ``n`` standard
complex normal (``E|n|^2 = 1``), so ``eps`` is the noise-to-signal amplitude
ratio: SNR 10^4 is ``eps = 1e-4``; 0.1 %, 1 %, 10 % are ``eps = 1e-3, 1e-2, 1e-1``.

Estimators, all from ``dsp_service.modal``:

* per-triplet VRM: adjacent bins ``(k, k+1, k+2)`` for every ``k`` in a band
  around the peak, solved with the corrected [C-12] (``vrm_lambdas``), read as
  a viscous mode (``vrm_modal``);
* the averaged VRM estimate: the mean of the per-triplet ``f_n`` and ``zeta``
  over the physical triplets (``Re lambda > 0``, ``0 < zeta < 0.5``) whose
  centre lies inside the half-power band, as the thesis averages triplets;
* the identifier's robust VRM (``VrmEstimator``: wide triplets, weighted
  mean of lambda);
* FWHM: three-bin parabolic peak (``refine_peak``), half-power crossings
  (``half_power_bandwidth``), exact inversion (``zeta_from_fwhm_exact``);
  its natural frequency is the peak frequency over ``sqrt(1 - 2 zeta^2)``.

Errors are over Monte-Carlo noise draws (``ctx.rng('vrm-noise')``): median
and 90th percentile of the relative error, and the fraction of draws with
no estimate.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from dsp_service.modal import (
    VrmEstimator,
    half_power_bandwidth,
    refine_peak,
    vrm_lambdas,
    vrm_modal,
    zeta_from_fwhm_exact,
)
from workbench.experiments.framework import ExperimentContext, experiment
from workbench.experiments.report import Report, new_figure

F_N_HZ = 4.4
ZETA = 0.09
FS_HZ = 200.0
N_FFT = 2048
SEARCH_HZ = (1.0, 20.0)
TRIPLET_SPAN_BINS = 12
"""Adjacent triplets are centred on every bin within this many bins of the peak (about 3 half-power half-widths)."""
NOISE_LEVELS: tuple[tuple[str, float], ...] = (("SNR 1e4", 1e-4), ("0.1 %", 1e-3), ("1 %", 1e-2), ("10 %", 1e-1))
METHODS = ("vrm_avg", "vrm_robust", "fwhm")
METHOD_LABELS = {
    "vrm_avg": "VRM, mean of adjacent triplets",
    "vrm_robust": "VRM, identifier's estimator",
    "fwhm": "FWHM (exact inversion)",
    "peak": "peak bin (parabolic)",
}


def grid() -> np.ndarray:
    return np.arange(N_FFT // 2 + 1) * FS_HZ / N_FFT


def single_mode_frf(freqs: np.ndarray, f_n: float = F_N_HZ, zeta: float = ZETA) -> np.ndarray:
    wn = 2 * math.pi * f_n
    w = 2 * math.pi * freqs
    return wn * wn / (wn * wn - w * w + 2j * zeta * wn * w)


def add_noise(h: np.ndarray, eps: float, rng: np.random.Generator) -> np.ndarray:
    n = (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / math.sqrt(2.0)
    return h + eps * np.abs(h) * n


def per_triplet(h: np.ndarray, freqs: np.ndarray, k0: int, span: int) -> dict[str, np.ndarray]:
    """Adjacent-triplet VRM for centres ``k0 - span .. k0 + span``: centre frequency, f_n, zeta, physical."""
    centres = np.arange(max(k0 - span, 1), min(k0 + span, freqs.size - 2) + 1)
    a, b, c = centres - 1, centres, centres + 1
    w = 2 * math.pi * freqs
    lam, weight = vrm_lambdas(h[a], h[b], h[c], w[a], w[b], w[c])
    wn, z = vrm_modal(lam, "viscous")
    physical = (weight > 0) & (lam.real > 0) & (z > 0) & (z < 0.5)
    return {"centre_hz": freqs[centres], "centre_bin": centres, "f_n": wn / (2 * math.pi), "zeta": z, "physical": physical}


def estimate_all(h: np.ndarray, freqs: np.ndarray, robust: VrmEstimator) -> dict[str, tuple[float, float] | None]:
    """(f_n, zeta) by each method on one FRF (None where a method gives nothing), and the peak bin's frequency."""
    mag = np.abs(h)
    lo, hi = (int(np.searchsorted(freqs, f)) for f in SEARCH_HZ)
    k0 = lo + int(np.argmax(mag[lo:hi]))
    d, lv = refine_peak(mag, k0)
    df = float(freqs[1] - freqs[0])
    f_peak = float(freqs[k0]) + d * df
    out: dict[str, tuple[float, float] | None] = {"peak": (f_peak, math.nan)}
    band = half_power_bandwidth(mag, freqs, k0, math.exp(lv))
    half_bins = 4.0
    if band is not None:
        bw = band[1] - band[0]
        z = zeta_from_fwhm_exact(bw, f_peak)
        out["fwhm"] = (f_peak / math.sqrt(max(1e-12, 1 - 2 * z * z)), z)
        half_bins = 0.5 * bw / df
    else:
        out["fwhm"] = None
    tri = per_triplet(h, freqs, k0, TRIPLET_SPAN_BINS)
    inside = tri["physical"] & (np.abs(tri["centre_bin"] - k0) <= max(1.0, half_bins))
    out["vrm_avg"] = (float(np.mean(tri["f_n"][inside])), float(np.mean(tri["zeta"][inside]))) if inside.any() else None
    r = robust.estimate(h, freqs, k0, half_bins)
    out["vrm_robust"] = (r[0], r[1]) if r is not None else None
    return out


def _stats(errors: list[float], n_draws: int) -> dict[str, float]:
    e = np.abs(np.asarray(errors, dtype=float))
    return {
        "median_abs_rel_error": float(np.median(e)) if e.size else math.nan,
        "p90_abs_rel_error": float(np.percentile(e, 90)) if e.size else math.nan,
        "max_abs_rel_error": float(np.max(e)) if e.size else math.nan,
        "failure_fraction": 1.0 - e.size / n_draws,
    }


@experiment(
    "vrm",
    section="App. C, Figs. C.1–C.6",
    description="VRM frequency and damping per bin triplet and averaged on a noisy synthetic 4.4 Hz, ζ 0.09 FRF (SNR 1e4, 0.1/1/10 % noise), against FWHM",
)
def run(ctx: ExperimentContext) -> Report:
    rep = ctx.report("Variable Residue Method against FWHM on a noisy single-mode FRF")
    freqs = grid()
    h0 = single_mode_frf(freqs)
    robust = VrmEstimator()
    n_draws = 40 if ctx.quick else 1000
    rng = ctx.rng("vrm-noise")
    show_rng = ctx.rng("vrm-example")

    rep.text(
        f"Synthetic receptance of one viscous mode, f_n = {F_N_HZ} Hz, ζ = {ZETA}, on {N_FFT} points at {FS_HZ:g} Hz "
        f"(bin {FS_HZ / N_FFT:.4f} Hz; the half-power half-width is {ZETA * F_N_HZ / (FS_HZ / N_FFT):.1f} bins). "
        "Complex noise proportional to |H| at each bin (ε = noise/signal amplitude: SNR 10⁴ is ε = 10⁻⁴). "
        f"{n_draws} noise draws per level. All estimators are `dsp_service.modal`'s."
    )

    examples = _example_draws(rep, h0, show_rng, freqs, robust)
    _triplet_figures(rep, examples)
    summary = _monte_carlo(ctx, rep, n_draws, freqs, robust, h0, rng)
    _error_table(rep, summary, n_draws)
    _error_figure(rep, summary)
    s10 = _accuracy_checks(rep, summary, examples, n_draws)
    _fwhm_comparison(rep, summary, s10)
    return rep


def _example_draws(rep: Report, h0: np.ndarray, show_rng: np.random.Generator, freqs: np.ndarray, robust: VrmEstimator) -> dict[str, dict[str, Any]]:
    """One noise draw per level: the per-triplet estimates and every estimator's result."""
    examples: dict[str, dict[str, Any]] = {}
    for label, eps in NOISE_LEVELS:
        h = add_noise(h0, eps, show_rng)
        mag = np.abs(h)
        lo, hi = (int(np.searchsorted(freqs, f)) for f in SEARCH_HZ)
        k0 = lo + int(np.argmax(mag[lo:hi]))
        tri = per_triplet(h, freqs, k0, TRIPLET_SPAN_BINS)
        est = estimate_all(h, freqs, robust)
        examples[label] = {"eps": eps, "k0": k0, "triplets": tri, "estimates": est}
    rep.results["example_draw"] = {
        label: {
            "eps": ex["eps"],
            "peak_bin": ex["k0"],
            "triplet_centre_hz": ex["triplets"]["centre_hz"],
            "triplet_f_n_hz": ex["triplets"]["f_n"],
            "triplet_zeta": ex["triplets"]["zeta"],
            "triplet_physical": ex["triplets"]["physical"],
            "estimates": {m: (list(v) if v is not None else None) for m, v in ex["estimates"].items()},
        }
        for label, ex in examples.items()
    }
    return examples


def _triplet_figures(rep: Report, examples: dict[str, dict[str, Any]]) -> None:
    """The per-triplet frequency and damping figures of the example draws."""
    for quantity, truth, unit, fname in (("f_n", F_N_HZ, "Hz", "vrm_triplets_frequency.png"), ("zeta", ZETA, "", "vrm_triplets_damping.png")):
        fig = new_figure(10.0, 6.0)
        axes = fig.subplots(2, 2, sharex=True).ravel()
        for ax, (label, ex) in zip(axes, examples.items()):
            tri = ex["triplets"]
            ph = tri["physical"]
            ax.plot(tri["centre_hz"][ph], tri[quantity][ph], "o", ms=4, mfc="none", label="per triplet")
            if (~ph).any():
                ax.plot(tri["centre_hz"][~ph], np.full((~ph).sum(), truth), "x", color="tab:red", ms=5, label="non-physical (not averaged)")
            ax.axhline(truth, color="k", lw=0.9, label="truth")
            idx = 0 if quantity == "f_n" else 1
            for m, style in (("vrm_avg", "--"), ("vrm_robust", "-."), ("fwhm", ":")):
                v = ex["estimates"].get(m)
                if v is not None:
                    ax.axhline(
                        v[idx], ls=style, lw=1.2, color={"vrm_avg": "tab:green", "vrm_robust": "tab:purple", "fwhm": "tab:orange"}[m], label=METHOD_LABELS[m]
                    )
            ax.axvspan(F_N_HZ * (1 - ZETA), F_N_HZ * (1 + ZETA), color="0.9", zorder=0)
            ax.set_title(f"noise {label}", fontsize=9)
            ax.grid(True, lw=0.3)
            if quantity == "zeta":
                ax.set_yscale("log")
                ax.set_ylim(ZETA / 30, 0.5)
            else:
                ax.set_ylim(F_N_HZ * 0.9, F_N_HZ * 1.1)
        for ax in axes[2:]:
            ax.set_xlabel("triplet centre frequency (Hz)")
        for ax in axes[::2]:
            ax.set_ylabel(f"{'natural frequency' if quantity == 'f_n' else 'damping ratio'}{' (' + unit + ')' if unit else ''}")
        axes[0].legend(fontsize=6.5, loc="best")
        name = "frequency" if quantity == "f_n" else "damping"
        rep.figure(
            fig,
            fname,
            f"VRM {name} estimate of each adjacent-bin triplet (one noise draw per level) against the truth; shaded: the half-power band.",
        )


def _monte_carlo(
    ctx: ExperimentContext, rep: Report, n_draws: int, freqs: np.ndarray, robust: VrmEstimator, h0: np.ndarray, rng: np.random.Generator
) -> dict[str, dict]:
    """Every estimator's relative errors over ``n_draws`` noise draws per level."""
    summary: dict[str, dict] = {}
    for label, eps in ctx.progress(NOISE_LEVELS, "VRM noise levels"):
        errs: dict[str, dict[str, list[float]]] = {m: {"f": [], "zeta": []} for m in (*METHODS, "peak")}
        for _ in range(n_draws):
            est = estimate_all(add_noise(h0, eps, rng), freqs, robust)
            for m, v in est.items():
                if v is None:
                    continue
                errs[m]["f"].append(v[0] / F_N_HZ - 1.0)
                if m != "peak":
                    errs[m]["zeta"].append(v[1] / ZETA - 1.0)
        summary[label] = {"eps": eps}
        for m in (*METHODS, "peak"):
            summary[label][m] = {"frequency": _stats(errs[m]["f"], n_draws)}
            if m != "peak":
                summary[label][m]["damping"] = _stats(errs[m]["zeta"], n_draws)
                z = np.asarray(errs[m]["zeta"]) + 1.0
                summary[label][m]["damping"]["within_order_of_magnitude"] = (
                    float(np.mean((z > 0.1) & (z < 10.0))) * (1.0 - summary[label][m]["damping"]["failure_fraction"]) if z.size else 0.0
                )
    rep.results["monte_carlo"] = {"n_draws": n_draws, "levels": summary}
    rep.results["truth"] = {"f_n_hz": F_N_HZ, "zeta": ZETA, "fs_hz": FS_HZ, "fft_width": N_FFT}
    return summary


def _error_table(rep: Report, summary: dict[str, dict], n_draws: int) -> None:
    """The table of errors over the noise draws."""
    rep.heading("Errors over noise draws")
    rows = []
    for label, s in summary.items():
        for m in METHODS:
            f, z = s[m]["frequency"], s[m]["damping"]
            rows.append(
                [
                    label,
                    METHOD_LABELS[m],
                    100 * f["median_abs_rel_error"],
                    100 * f["p90_abs_rel_error"],
                    100 * z["median_abs_rel_error"],
                    100 * z["p90_abs_rel_error"],
                    100 * z["within_order_of_magnitude"],
                    100 * f["failure_fraction"],
                ]
            )
        pk = s["peak"]["frequency"]
        rows.append([label, METHOD_LABELS["peak"], 100 * pk["median_abs_rel_error"], 100 * pk["p90_abs_rel_error"], "–", "–", "–", 0.0])
    rep.table(
        ["noise", "method", "f_n median |err| (%)", "f_n p90 (%)", "ζ median |err| (%)", "ζ p90 (%)", "ζ within ×10 (% of draws)", "no estimate (%)"],
        rows,
        caption=f"Relative errors, {n_draws} draws per level. The peak bin's row is the peak frequency against f_n: "
        f"the peak of a ζ = {ZETA} receptance lies {100 * (1 - math.sqrt(1 - 2 * ZETA**2)):.2f} % below f_n. "
        f"VRM's ζ error at low noise is the viscous reading's own bias (about +0.4 % at ζ = 0.09, see `dsp_service.modal`).",
        digits=3,
    )


def _error_figure(rep: Report, summary: dict[str, dict]) -> None:
    """Median relative error of each estimator against the noise level."""
    fig = new_figure(9.0, 3.8)
    ax1, ax2 = fig.subplots(1, 2)
    eps_arr = np.array([e for _, e in NOISE_LEVELS])
    for m, mk in (("vrm_avg", "o-"), ("vrm_robust", "s-"), ("fwhm", "^--"), ("peak", "v:")):
        ax1.loglog(eps_arr, [100 * max(summary[l][m]["frequency"]["median_abs_rel_error"], 1e-6) for l, _ in NOISE_LEVELS], mk, label=METHOD_LABELS[m])
        if m != "peak":
            ax2.loglog(eps_arr, [100 * max(summary[l][m]["damping"]["median_abs_rel_error"], 1e-6) for l, _ in NOISE_LEVELS], mk, label=METHOD_LABELS[m])
    for ax, t in ((ax1, "natural frequency"), (ax2, "damping ratio")):
        ax.set_xlabel("noise ε (noise/signal amplitude)")
        ax.set_ylabel("median |relative error| (%)")
        ax.set_title(t, fontsize=9)
        ax.grid(True, which="both", lw=0.3)
    ax1.legend(fontsize=7)
    rep.figure(fig, "vrm_vs_fwhm_errors.png", "Median relative error of each estimator against the noise level.")


def _accuracy_checks(rep: Report, summary: dict[str, dict], examples: dict[str, dict[str, Any]], n_draws: int) -> Any:
    """The checks and the thesis's claims on accuracy at SNR 1e4 and damping at 10 % noise."""
    s4 = summary["SNR 1e4"]
    ex4 = examples["SNR 1e4"]["estimates"]["vrm_avg"]
    ok4 = ex4 is not None and abs(ex4[0] / F_N_HZ - 1) < 0.01 and abs(ex4[1] / ZETA - 1) < 0.01
    rep.check(
        "VRM (averaged triplets) within 1 % at SNR 1e4, shown draw",
        ok4,
        f"f_n {ex4[0]:.4f} Hz, ζ {ex4[1]:.5f}" if ex4 else "no estimate",
    )
    worst4 = max(s4[m][q]["max_abs_rel_error"] for m in ("vrm_avg", "vrm_robust") for q in ("frequency", "damping"))
    rep.check(
        "VRM (both) within 1 % at SNR 1e4, every draw", worst4 < 0.01 and s4["vrm_avg"]["frequency"]["failure_fraction"] == 0, f"worst {100 * worst4:.3f} %"
    )
    s10 = summary["10 %"]
    rep.check(
        "VRM damping within an order of magnitude at 10 % noise (robust estimator, ≥ 90 % of draws)",
        s10["vrm_robust"]["damping"]["within_order_of_magnitude"] >= 0.9,
        f"{100 * s10['vrm_robust']['damping']['within_order_of_magnitude']:.1f} % of draws (mean of triplets: {100 * s10['vrm_avg']['damping']['within_order_of_magnitude']:.1f} %)",
    )
    rep.thesis(
        "VRM is accurate at SNR 10⁴.",
        f"Median |error| f_n {100 * s4['vrm_avg']['frequency']['median_abs_rel_error']:.3f} %, ζ {100 * s4['vrm_avg']['damping']['median_abs_rel_error']:.3f} % "
        f"(mean of adjacent triplets); worst over {n_draws} draws {100 * worst4:.3f} %.",
        worst4 < 0.01,
    )
    return s10


def _fwhm_comparison(rep: Report, summary: dict[str, dict], s10: Any) -> None:
    """The thesis's claims comparing VRM with FWHM and with the initial peak."""
    better = {l: summary[l]["vrm_robust"]["damping"]["median_abs_rel_error"] < summary[l]["fwhm"]["damping"]["median_abs_rel_error"] for l, _ in NOISE_LEVELS}
    better_avg = {l: summary[l]["vrm_avg"]["damping"]["median_abs_rel_error"] < summary[l]["fwhm"]["damping"]["median_abs_rel_error"] for l, _ in NOISE_LEVELS}
    within = {m: s10[m]["damping"]["within_order_of_magnitude"] for m in METHODS}
    rep.thesis(
        "With 0.1–10 % noise VRM damping estimates stay within an order of magnitude.",
        "Median |ζ error| at 0.1 / 1 / 10 %: VRM (identifier) "
        + " / ".join(f"{100 * summary[l]['vrm_robust']['damping']['median_abs_rel_error']:.2g} %" for l in ("0.1 %", "1 %", "10 %"))
        + ", VRM (mean of adjacent triplets) "
        + " / ".join(f"{100 * summary[l]['vrm_avg']['damping']['median_abs_rel_error']:.2g} %" for l in ("0.1 %", "1 %", "10 %"))
        + f". Within ×10 of the truth at 10 % noise: {100 * within['vrm_robust']:.1f} % (identifier) and "
        f"{100 * within['vrm_avg']:.1f} % (triplet mean) of draws.",
        within["vrm_robust"] >= 0.9 and within["vrm_avg"] >= 0.9,
    )
    ids = [l for l, b in better.items() if b]
    avgs = [l for l, b in better_avg.items() if b]
    all_ids = len(ids) == len(NOISE_LEVELS)
    all_avgs = len(avgs) == len(NOISE_LEVELS)
    rep.thesis(
        "VRM damping is better than FWHM's.",
        "Median |ζ error| of FWHM at 0.1 / 1 / 10 %: "
        + " / ".join(f"{100 * summary[l]['fwhm']['damping']['median_abs_rel_error']:.2g} %" for l in ("0.1 %", "1 %", "10 %"))
        + f". The identifier's VRM (wide triplets, weighted) beats it at {', '.join(ids) or 'no level'}; "
        f"the plain mean of adjacent triplets at {', '.join(avgs) or 'no level'} (adjacent-bin differences are noise-dominated).",
        True if all_ids and all_avgs else ("partly" if all_ids or ids or avgs else False),
    )
    rep.thesis(
        "With noise, the VRM frequency estimate is only as good as the initial peak.",
        "Median |f_n error| at 0.1 / 1 / 10 %: VRM (identifier) "
        + " / ".join(f"{100 * summary[l]['vrm_robust']['frequency']['median_abs_rel_error']:.2g} %" for l in ("0.1 %", "1 %", "10 %"))
        + "; the peak bin (parabolic) "
        + " / ".join(f"{100 * summary[l]['peak']['frequency']['median_abs_rel_error']:.2g} %" for l in ("0.1 %", "1 %", "10 %"))
        + " (of which 0.81 % is the peak's own offset from f_n). Here VRM's f_n is far better than the peak it "
        "starts from: on a noisy but otherwise exact single-mode FRF the triplets carry the frequency information.",
        False,
    )
