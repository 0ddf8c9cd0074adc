"""``fwhm-error``: accuracy of the half-power (FWHM) damping approximation [B.1] (thesis App. B, Fig. B.1).

For the displacement power spectrum ``P(r) = a / ((1 - r^2)^2 + 4 zeta^2 r^2)``
[B.2] the exact half-power width follows from ``dsp_service.modal``
(``half_power_points``, ``fwhm_ratio``).  [B.1] reads ``zeta ~ dw / (2 w_n)``.
Two readings of ``w_n`` are compared: the true natural frequency (the
thesis's statement, "within 1 % for zeta < 0.1") and the peak frequency (what
a measurement gives, ``zeta_fwhm_approx(dw, f_peak)``).  The exact inversion
``zeta_from_fwhm_exact`` is checked to return ``zeta``, and the half-power
points are checked against a brute-force root search of ``P(r) = P_max / 2``.

A second part measures the same thing on the identifier's grid (2048 bins at
200 Hz, 0.0977 Hz, a 4.4 Hz mode): ``half_power_bandwidth`` on the sampled
``|H|`` with the three-bin peak refinement, where the bin width, not [B.1],
limits light damping.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq, minimize_scalar

from dsp_service.modal import (
    fwhm_ratio,
    half_power_bandwidth,
    half_power_points,
    refine_peak,
    zeta_from_fwhm_exact,
    zeta_fwhm_approx,
)
from workbench.experiments.framework import ExperimentContext, experiment
from workbench.experiments.report import Report, new_figure

ZETA_MIN = 0.001
ZETA_MAX = 0.2
GRID_FN_HZ = 4.4
GRID_FS_HZ = 200.0
GRID_N = 2048


def approx_error_true_wn(zeta: float) -> float:
    """Relative error of [B.1] with the true ``w_n``: ``(dw / 2 w_n - zeta) / zeta``."""
    r1, r2 = half_power_points(zeta)
    return zeta_fwhm_approx(r2 - r1, 1.0) / zeta - 1.0


def approx_error_peak(zeta: float) -> float:
    """Relative error of [B.1] with ``w_n`` taken as the peak frequency ``w_p = w_n sqrt(1 - 2 zeta^2)``."""
    rho = fwhm_ratio(zeta)  # dw / w_p
    return zeta_fwhm_approx(rho, 1.0) / zeta - 1.0


def brute_force_half_power(zeta: float) -> tuple[float, float]:
    """Half-power points of ``P(r)`` by root search (independent of the closed form)."""
    den = lambda r: (1 - r * r) ** 2 + 4 * zeta * zeta * r * r  # noqa: E731
    peak = minimize_scalar(den, bounds=(0.0, 1.0 + 10 * zeta), method="bounded", options={"xatol": 1e-14})
    rp, dmin = float(peak.x), float(peak.fun)
    f = lambda r: den(r) - 2.0 * dmin  # noqa: E731  P = P_max / 2  <=>  den = 2 den_min
    return brentq(f, 1e-9, rp, xtol=1e-15), brentq(f, rp, 3.0, xtol=1e-15)


def _crossing(fun, level: float, lo: float, hi: float) -> float | None:
    a, b = fun(lo) - level, fun(hi) - level
    if a * b > 0:
        return None
    return float(brentq(lambda z: fun(z) - level, lo, hi, xtol=1e-12))


def grid_estimate(zeta: float) -> dict[str, float | None]:
    """FWHM on the 2048-bin grid: the identifier's steps on an exact single-mode |H|."""
    freqs = np.arange(GRID_N // 2 + 1) * GRID_FS_HZ / GRID_N
    wn = 2 * math.pi * GRID_FN_HZ
    w = 2 * math.pi * freqs
    h = 1.0 / (wn * wn - w * w + 2j * zeta * wn * w)
    mag = np.abs(h)
    k = int(np.argmax(mag[1:])) + 1
    d, lv = refine_peak(mag, k)
    f_peak = float(freqs[k] + d * (freqs[1] - freqs[0]))
    band = half_power_bandwidth(mag, freqs, k, math.exp(lv), max_bins=512)
    if band is None:
        return {"zeta_exact": None, "zeta_b1": None, "f_peak_hz": f_peak}
    bw = band[1] - band[0]
    return {
        "zeta_exact": zeta_from_fwhm_exact(bw, f_peak),
        "zeta_b1": zeta_fwhm_approx(bw, f_peak),
        "f_peak_hz": f_peak,
        "bandwidth_hz": bw,
        "bins_across_band": bw / (freqs[1] - freqs[0]),
    }


@experiment(
    "fwhm-error",
    section="App. B, Fig. B.1",
    description="Relative error of the FWHM damping approximation [B.1] against the exact half-power width, ζ 0.001–0.2, and on the 2048-bin grid",
)
def run(ctx: ExperimentContext) -> Report:
    rep = ctx.report("FWHM damping: [B.1] against the exact half-power width")
    n = 41 if ctx.quick else 401
    zetas = np.geomspace(ZETA_MIN, ZETA_MAX, n)

    err_true = np.array([approx_error_true_wn(z) for z in zetas])
    err_peak = np.array([approx_error_peak(z) for z in zetas])
    roundtrip = np.array([zeta_from_fwhm_exact(fwhm_ratio(z), 1.0) / z - 1.0 for z in zetas])
    n_bf = 9 if ctx.quick else 41
    bf_z = np.geomspace(ZETA_MIN, ZETA_MAX, n_bf)
    bf_dev = max(max(abs(a - b) for a, b in zip(half_power_points(z), brute_force_half_power(z), strict=True)) for z in bf_z)
    cross_true = _crossing(approx_error_true_wn, 0.01, ZETA_MIN, ZETA_MAX)
    cross_peak = _crossing(approx_error_peak, 0.01, ZETA_MIN, ZETA_MAX)
    at = {f"{z:g}": {"true_wn": approx_error_true_wn(z), "peak": approx_error_peak(z)} for z in (0.001, 0.01, 0.05, 0.09, 0.1, 0.2)}
    rep.results["analytic"] = {
        "zeta": zetas.tolist(),
        "rel_error_true_wn": err_true.tolist(),
        "rel_error_peak_wn": err_peak.tolist(),
        "crossing_1pct_true_wn": cross_true,
        "crossing_1pct_peak_wn": cross_peak,
        "rel_error_at": at,
        "exact_inversion_max_rel_error": float(np.max(np.abs(roundtrip))),
        "half_power_points_max_abs_dev_vs_brute_force": float(bf_dev),
        "monotonic_true_wn": bool(np.all(np.diff(err_true) > 0)),
    }

    _analytic_section(rep, n, bf_dev, n_bf, roundtrip, at, cross_true, cross_peak, zetas, err_true, err_peak)
    _grid_section(ctx, rep, zetas, err_peak)
    _checks(rep, zetas, err_true, err_peak, cross_true, bf_dev, roundtrip, at, cross_peak)
    return rep


def _analytic_section(
    rep: Report,
    n: int,
    bf_dev: float,
    n_bf: int,
    roundtrip: np.ndarray,
    at: dict[str, dict[str, float]],
    cross_true: float | None,
    cross_peak: float | None,
    zetas: np.ndarray,
    err_true: np.ndarray,
    err_peak: np.ndarray,
) -> None:
    """[B.1] against the exact width (Fig. B.1): text, tables and figure."""
    rep.heading("1. [B.1] against the exact width (Fig. B.1)")
    rep.text(
        "Half-power points of P(r) from `dsp_service.modal.half_power_points` "
        "(r₁,₂² = 1 − 2ζ² ∓ 2ζ√(1 − ζ²)); [B.1] ζ ≈ Δω/(2ω_n) via `zeta_fwhm_approx`. "
        f"{n} values of ζ, log-spaced from {ZETA_MIN} to {ZETA_MAX}. The closed-form half-power points agree with a "
        f"brute-force root search of P(r) = P_max/2 to {bf_dev:.1e} (in r) at {n_bf} values of ζ, and the exact "
        f"inversion `zeta_from_fwhm_exact` returns ζ to {np.max(np.abs(roundtrip)):.1e} (relative)."
    )
    rep.table(
        ["ζ", "error with true ω_n (%)", "error with ω_n = peak (%)"],
        [[float(z), 100 * v["true_wn"], 100 * v["peak"]] for z, v in zip((0.001, 0.01, 0.05, 0.09, 0.1, 0.2), at.values())],
        caption="Relative error of [B.1] (positive: overestimates ζ)",
    )
    rep.table(
        ["reading of ω_n in [B.1]", "error reaches 1 % at ζ ="],
        [["true natural frequency", cross_true if cross_true else "never"], ["peak frequency", cross_peak if cross_peak else "never"]],
    )
    fig = new_figure(7.5, 4.3)
    ax = fig.add_subplot(1, 1, 1)
    ax.loglog(zetas, 100 * np.abs(err_true), label="[B.1] with the true ω_n")
    ax.loglog(zetas, 100 * np.abs(err_peak), "--", label="[B.1] with ω_n = peak frequency")
    ax.axhline(1.0, color="0.4", ls=":", lw=0.9)
    for c, col in ((cross_true, "tab:blue"), (cross_peak, "tab:orange")):
        if c:
            ax.axvline(c, color=col, ls=":", lw=0.9)
            ax.annotate(f"ζ = {c:.4f}", (c, 1.0), textcoords="offset points", xytext=(-60 if col == "tab:orange" else 4, 8), fontsize=8, color=col)
    ax.set_xlabel("damping ratio ζ")
    ax.set_ylabel("relative error of ζ (%)")
    ax.set_title("FWHM approximation error (Fig. B.1)")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8)
    rep.figure(fig, "fwhm_error.png", "Relative error of the [B.1] approximation against the exact damping; dotted: 1 %.")


def _grid_section(ctx: ExperimentContext, rep: Report, zetas: np.ndarray, err_peak: np.ndarray) -> None:
    """FWHM on the identifier's grid: 2048 bins at 200 Hz, a 4.4 Hz mode."""
    rep.heading("2. On the identifier's grid: 2048 bins at 200 Hz, a 4.4 Hz mode")
    gz = np.geomspace(0.005, ZETA_MAX, 12 if ctx.quick else 60)
    grid = [grid_estimate(float(z)) for z in gz]
    ge_exact = np.array([(g["zeta_exact"] / z - 1.0) if g["zeta_exact"] else np.nan for g, z in zip(grid, gz)])
    ge_b1 = np.array([(g["zeta_b1"] / z - 1.0) if g["zeta_b1"] else np.nan for g, z in zip(grid, gz)])
    bins = np.array([g.get("bins_across_band") or np.nan for g in grid])
    rep.results["grid"] = {
        "frequency_hz": GRID_FN_HZ,
        "sample_rate_hz": GRID_FS_HZ,
        "fft_width": GRID_N,
        "bin_hz": GRID_FS_HZ / GRID_N,
        "zeta": gz.tolist(),
        "rel_error_exact_inversion": ge_exact.tolist(),
        "rel_error_b1_peak": ge_b1.tolist(),
        "bins_across_band": bins.tolist(),
    }
    pick = [0.01, 0.02, 0.05, 0.09, 0.2]
    rows = []
    for z in pick:
        g = grid_estimate(z)
        rows.append([z, g.get("bins_across_band"), 100 * ((g["zeta_exact"] or math.nan) / z - 1), 100 * ((g["zeta_b1"] or math.nan) / z - 1)])
    rep.results["grid"]["at"] = {f"{r[0]:g}": {"bins_across_band": r[1], "rel_error_exact_pct": r[2], "rel_error_b1_pct": r[3]} for r in rows}
    rep.text(
        "The exact single-mode receptance sampled on the bins; peak by the three-bin parabola on ln|H| "
        "(`refine_peak`), half-power crossings interpolated linearly in power (`half_power_bandwidth`)."
    )
    rep.table(["ζ", "bins across the half-power band", "exact inversion error (%)", "[B.1] at the peak error (%)"], rows)
    fig = new_figure(7.5, 4.0)
    ax = fig.add_subplot(1, 1, 1)
    ax.semilogx(gz, 100 * ge_exact, "o-", ms=3, label="exact inversion, from bins")
    ax.semilogx(gz, 100 * ge_b1, "s--", ms=3, label="[B.1] with ω_n = peak, from bins")
    ax.semilogx(zetas, 100 * err_peak, color="0.5", lw=0.8, label="[B.1] analytic (peak)")
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlim(gz[0] * 0.9, gz[-1] * 1.1)
    ax.set_xlabel("damping ratio ζ")
    ax.set_ylabel("relative error of ζ (%)")
    ax.set_title(f"FWHM on a {GRID_FS_HZ / GRID_N:.4f} Hz grid, {GRID_FN_HZ} Hz mode")
    ax.grid(True, which="both", lw=0.3)
    ax.legend(fontsize=8)
    rep.figure(fig, "fwhm_on_grid.png", "FWHM damping from 2048 bins at 200 Hz: the bin width dominates at light damping.")


def _checks(
    rep: Report,
    zetas: np.ndarray,
    err_true: np.ndarray,
    err_peak: np.ndarray,
    cross_true: float | None,
    bf_dev: float,
    roundtrip: np.ndarray,
    at: dict[str, dict[str, float]],
    cross_peak: float | None,
) -> None:
    """The checks and the comparison with the thesis."""
    below = zetas < 0.098
    rep.check(
        "[B.1] (true ω_n) within 1 % for ζ < 0.098",
        bool(np.all(np.abs(err_true[below]) < 0.01)),
        f"max {100 * np.max(np.abs(err_true[below])):.3f} % below 0.098",
    )
    rep.check(
        "[B.1] error grows with ζ",
        rep.results["analytic"]["monotonic_true_wn"] and bool(np.all(np.diff(err_peak) > 0)),
        f"{100 * err_true[0]:.2e} % at ζ = {ZETA_MIN}, {100 * err_true[-1]:.2f} % at ζ = {ZETA_MAX}",
    )
    rep.check(
        "1 % crossing (true ω_n) between 0.09 and 0.11",
        cross_true is not None and 0.09 < cross_true < 0.11,
        f"ζ = {cross_true:.5f}" if cross_true else "no crossing",
    )
    rep.check("closed-form half-power points match a root search", bf_dev < 1e-9, f"max |Δr| = {bf_dev:.1e}")
    rep.check("exact inversion returns ζ", float(np.max(np.abs(roundtrip))) < 1e-9, f"max rel. error {np.max(np.abs(roundtrip)):.1e}")
    rep.thesis(
        "The [B.1] approximation is within 1 % for ζ < 0.1, the error shrinking as ζ falls.",
        f"With the true ω_n the error reaches 1 % at ζ = {cross_true:.4f} ({100 * at['0.1']['true_wn']:.2f} % at 0.1, "
        f"{100 * at['0.09']['true_wn']:.2f} % at the arm's 0.09); it falls as ζ² ({100 * at['0.01']['true_wn']:.4f} % at 0.01). "
        f"Taking ω_n as the peak frequency, as a measurement must, doubles it: 1 % at ζ = {cross_peak:.4f}.",
        cross_true is not None and 0.09 < cross_true < 0.11,
    )
    g09 = rep.results["grid"]["at"]["0.09"]["rel_error_exact_pct"]
    g01 = rep.results["grid"]["at"]["0.01"]["rel_error_exact_pct"]
    g05 = rep.results["grid"]["at"]["0.05"]["rel_error_exact_pct"]
    rep.thesis(
        "FWHM uses only two bins, so its precision is limited by the bin width; the thesis used it only off line.",
        f"On the 0.0977 Hz grid the exact inversion is off by {g09:+.2f} % at ζ = 0.09, {g05:+.2f} % at 0.05 and {g01:+.1f} % at 0.01 "
        "(crossings interpolated linearly in power; the error depends on where the bins fall, not smoothly on ζ): "
        "the grid, not [B.1], limits light damping.",
        abs(g01) > 10 * abs(g09),
    )
