"""``oatf-response``: the discrete OATF's frequency response (thesis §3.3 Figs. 3.7-3.8, Fig. 4.8).

Part 1, the thesis's example: a 51 Hz mode sampled at 500 Hz.  The robust
delay ``T1 = pi / w_d`` is 9.80 ms, ``n1 = int(T1 / Ts) = 4`` samples.
Computing the coefficients from ``n1 Ts`` [3-34] (``design_stage``) puts a
zero exactly on 51 Hz; computing them from ``T1`` (``design_stage_continuous``)
with the taps still at ``n1`` misplaces it.  We report where that design's
notch actually is (the minimum of ``|F|`` found numerically, and the zeros of
the polynomial in ``z``) and ``|F(51 Hz)|`` for both.

Part 2, Fig. 4.8: the OATF for a 4.4 Hz mode at 200 Hz designed with damping
0.09 and 0.01, and the percentage residual vibration ``V`` of each design
over ``w / w_design`` (Singer and Seering's sensitivity curve, notes
formula, ``controller.oatf.residual_vibration``), on a mode whose damping is
the design damping and on the arm's own ``zeta = 0.09`` mode.
"""

from __future__ import annotations

import numpy as np

from controller.oatf import StageDesign, design_stage, design_stage_continuous, frequency_response, kernel_impulses, residual_vibration, robust_delay_s
from workbench.experiments.framework import ExperimentContext, experiment
from workbench.experiments.lib.oatf_zeros import abs_at_pole, notch, zeros, zeros_hz
from workbench.experiments.lib.spectrum_features import band_below
from workbench.experiments.report import Report, new_figure

EXAMPLE_F_HZ = 51.0
EXAMPLE_FS_HZ = 500.0
EXAMPLE_ZETAS = (0.0, 0.02, 0.09)
"""Part 1 is shown undamped (as the thesis's example); the residual vibration is also given for damped modes."""
ARM_F_HZ = 4.4
ARM_FS_HZ = 200.0
DESIGN_ZETAS = (0.09, 0.01)
ARM_ZETA = 0.09


@experiment(
    "oatf-response",
    section="§3.3 Figs. 3.7–3.8, Fig. 4.8",
    description="Discrete vs continuous-delay OATF design (51 Hz at 500 Hz); OATF responses and residual-vibration sensitivity for ζ 0.09 and 0.01 at 4.4 Hz",
)
def run(ctx: ExperimentContext) -> Report:
    rep = ctx.report("OATF frequency response and sensitivity")
    n_grid = 2001 if ctx.quick else 20001
    ts = 1.0 / EXAMPLE_FS_HZ

    disc, cont = _example_designs(rep, ts, n_grid)
    _example_tables(rep, disc, cont)
    _example_figure(rep, n_grid, disc, cont, ts)
    designs, f2, arm = _arm_designs(rep, n_grid)
    ratio, sens = _arm_sensitivity(ctx, rep, designs, arm)
    _arm_response_figure(rep, designs, f2)
    _sensitivity_figure(rep, designs, ratio)
    _sensitivity_table(rep, sens)
    _checks(rep)
    return rep


def _example_designs(rep: Report, ts: float, n_grid: int) -> tuple[StageDesign, StageDesign]:
    """The 51 Hz example at 500 Hz (Figs. 3.7, 3.8): both designs; their notches and residual vibration into the results."""
    rep.heading("1. Integer delay versus continuous delay: 51 Hz at 500 Hz (Figs. 3.7, 3.8)")
    t1 = robust_delay_s(EXAMPLE_F_HZ, 0.0)
    disc = design_stage(EXAMPLE_F_HZ, 0.0, ts)
    cont = design_stage_continuous(EXAMPLE_F_HZ, 0.0, ts)
    f_disc, m_disc = notch(disc, EXAMPLE_F_HZ, EXAMPLE_FS_HZ / 2, n_grid)
    f_cont, m_cont = notch(cont, EXAMPLE_F_HZ, EXAMPLE_FS_HZ / 2, n_grid)
    at51 = {
        "discrete": float(abs(frequency_response([EXAMPLE_F_HZ], [disc])[0])),
        "continuous": float(abs(frequency_response([EXAMPLE_F_HZ], [cont])[0])),
    }
    rv = {}
    for z in EXAMPLE_ZETAS:
        d = design_stage(EXAMPLE_F_HZ, z, ts)
        c = design_stage_continuous(EXAMPLE_F_HZ, z, ts)
        rv[str(z)] = {
            "discrete": float(residual_vibration(*kernel_impulses([d]), EXAMPLE_F_HZ, z)),
            "continuous": float(residual_vibration(*kernel_impulses([c]), EXAMPLE_F_HZ, z)),
            "discrete_at_pole_abs": abs_at_pole(d, EXAMPLE_F_HZ, z),
            "continuous_at_pole_abs": abs_at_pole(c, EXAMPLE_F_HZ, z),
        }
    rep.results["example_51hz"] = {
        "frequency_hz": EXAMPLE_F_HZ,
        "sample_rate_hz": EXAMPLE_FS_HZ,
        "zeta": 0.0,
        "t1_continuous_s": t1,
        "n1_samples": disc.delay_samples,
        "n1_ts_s": disc.delay_s,
        "coefficients_discrete": list(disc.coefficients),
        "coefficients_continuous": list(cont.coefficients),
        "abs_F_at_51hz": at51,
        "notch_discrete_hz": f_disc,
        "notch_discrete_abs": m_disc,
        "notch_continuous_hz": f_cont,
        "notch_continuous_abs": m_cont,
        "zeros_discrete": zeros_hz(disc),
        "zeros_continuous": zeros_hz(cont),
        "residual_vibration_at_51hz": rv,
    }
    return disc, cont


def _example_tables(rep: Report, disc: StageDesign, cont: StageDesign) -> None:
    """The 51 Hz example's text and tables."""
    ex = rep.results["example_51hz"]
    t1, at51, rv = ex["t1_continuous_s"], ex["abs_F_at_51hz"], ex["residual_vibration_at_51hz"]
    rep.text(
        f"Robust delay T1 = π/ω_d = {t1 * 1e3:.3f} ms; n1 = int(T1/Ts) = {disc.delay_samples} samples "
        f"({disc.delay_s * 1e3:.1f} ms). Both designs put their taps at 0, n1, 2·n1; they differ only in "
        "whether the coefficients come from n1·Ts [3-34] or from T1 [3-32]. The mode is undamped here, "
        "as in the thesis's illustration; the residual-vibration rows add damped modes."
    )
    rep.table(
        ["design", "coefficients a0, a1, a2", "|F(51 Hz)|", "notch nearest 51 Hz (Hz)", "|F| there", "zeros on the unit circle (Hz)"],
        [
            [
                name,
                ", ".join(f"{a:.4f}" for a in s.coefficients),
                at51[key],
                fn,
                mn,
                ", ".join(f"{z['frequency_hz']:.2f}" for z in zeros_hz(s) if abs(z["radius"] - 1) < 1e-6),
            ]
            for name, key, s, fn, mn in (
                ("from n1·Ts (discrete, [3-34])", "discrete", disc, ex["notch_discrete_hz"], ex["notch_discrete_abs"]),
                ("from T1 (continuous, [3-32])", "continuous", cont, ex["notch_continuous_hz"], ex["notch_continuous_abs"]),
            )
        ],
        caption="The 51 Hz example at 500 Hz (ζ = 0)",
    )
    rep.table(
        ["mode ζ", "V discrete", "V continuous", "|F| at the pole, discrete", "|F| at the pole, continuous"],
        [[float(z), r["discrete"], r["continuous"], r["discrete_at_pole_abs"], r["continuous_at_pole_abs"]] for z, r in rv.items()],
        caption="Residual vibration V of a 51 Hz mode after each design (fraction of an unshaped step) and |F| at the "
        "mode's pole z = e^(s·Ts); design ζ = mode ζ. (For a damped mode the zero sits on the pole, inside the unit circle.)",
    )


def _example_figure(rep: Report, n_grid: int, disc: StageDesign, cont: StageDesign, ts: float) -> None:
    """Magnitude response and zeros of the two 51 Hz designs."""
    f_cont = rep.results["example_51hz"]["notch_continuous_hz"]
    freqs = np.linspace(0.0, EXAMPLE_FS_HZ / 2, n_grid)
    fig = new_figure(9.0, 4.2)
    ax1, ax2 = fig.subplots(1, 2, width_ratios=[2.2, 1])
    for s, label, col in ((disc, "coefficients from n1·Ts", "tab:blue"), (cont, "coefficients from T1", "tab:red")):
        mag = np.abs(frequency_response(freqs, [s]))
        ax1.plot(freqs, 20 * np.log10(np.maximum(mag, 1e-6)), color=col, label=label)
    ax1.axvline(EXAMPLE_F_HZ, color="k", ls="--", lw=0.8, label="51 Hz mode")
    ax1.axvline(f_cont, color="tab:red", ls=":", lw=0.8, label=f"T1 design's notch {f_cont:.1f} Hz")
    ax1.set_xlabel("frequency (Hz)")
    ax1.set_ylabel("|F| (dB)")
    ax1.set_ylim(-120, 5)
    ax1.set_title("OATF for 51 Hz at 500 Hz, n1 = 4")
    ax1.legend(fontsize=7, loc="lower left")
    ax1.grid(True, lw=0.3)
    th = np.linspace(0, 2 * np.pi, 400)
    ax2.plot(np.cos(th), np.sin(th), color="0.6", lw=0.8)
    for s, col, mk in ((disc, "tab:blue", "o"), (cont, "tab:red", "x")):
        r = zeros(s)
        ax2.plot(r.real, r.imag, mk, color=col, mfc="none", ms=7)
    w51 = 2 * np.pi * EXAMPLE_F_HZ * ts
    ax2.plot([0, 1.2 * np.cos(w51)], [0, 1.2 * np.sin(w51)], "k--", lw=0.8)
    ax2.set_aspect("equal")
    ax2.set_title("zeros in the z-plane (o: n1·Ts, x: T1)", fontsize=9)
    ax2.grid(True, lw=0.3)
    rep.figure(fig, "oatf_51hz_at_500hz.png", "Magnitude response and zeros of the two designs; the dashed ray is 51 Hz.")


def _arm_designs(rep: Report, n_grid: int) -> tuple[dict[float, StageDesign], np.ndarray, dict[str, dict]]:
    """The 4.4 Hz designs at 200 Hz for design ζ 0.09 and 0.01 (Fig. 4.8) and their table."""
    rep.heading("2. OATF for a 4.4 Hz mode at 200 Hz, design ζ 0.09 and 0.01 (Fig. 4.8)")
    ts2 = 1.0 / ARM_FS_HZ
    designs = {z: design_stage(ARM_F_HZ, z, ts2) for z in DESIGN_ZETAS}
    f2 = np.linspace(0.0, ARM_FS_HZ / 2, n_grid)
    arm: dict[str, dict] = {}
    rows = []
    for z, s in designs.items():
        mag = np.abs(frequency_response(f2, [s]))
        band20 = band_below(f2, mag, ARM_F_HZ, 0.1)
        notch_f, notch_m = notch(s, ARM_F_HZ, ARM_FS_HZ / 2, n_grid)
        arm[str(z)] = {
            "design_zeta": z,
            "t1_robust_s": robust_delay_s(ARM_F_HZ, z),
            "n1_samples": s.delay_samples,
            "coefficients": list(s.coefficients),
            "abs_F_at_design": float(abs(frequency_response([ARM_F_HZ], [s])[0])),
            "abs_F_at_pole": abs_at_pole(s, ARM_F_HZ, z),
            "notch_hz": notch_f,
            "notch_abs": notch_m,
            "band_below_minus20db_hz": list(band20) if band20 else None,
            "band_below_minus20db_width_hz": (band20[1] - band20[0]) if band20 else None,
            "abs_F_at_2x_design": float(abs(frequency_response([2 * ARM_F_HZ], [s])[0])),
        }
        rows.append(
            [
                z,
                s.delay_samples,
                ", ".join(f"{a:.4f}" for a in s.coefficients),
                arm[str(z)]["abs_F_at_design"],
                arm[str(z)]["abs_F_at_pole"],
                notch_f,
                notch_m,
                f"{band20[0]:.2f}–{band20[1]:.2f} Hz" if band20 else "–",
            ]
        )
    rep.table(
        ["design ζ", "n1", "coefficients", "|F(4.4 Hz)|", "|F| at the pole", "notch (Hz)", "|F| at the notch", "|F| ≤ −20 dB over"],
        rows,
        caption="OATF designs for 4.4 Hz at 200 Hz (robust delay truncated to n1 samples)",
    )
    return designs, f2, arm


def _arm_sensitivity(ctx: ExperimentContext, rep: Report, designs: dict[float, StageDesign], arm: dict[str, dict]) -> tuple[np.ndarray, dict[str, dict]]:
    """Residual vibration of each 4.4 Hz design against the mode's frequency ratio."""
    # sensitivity curves
    n_ratio = 301 if ctx.quick else 2001
    ratio = np.linspace(0.0, 3.0, n_ratio)[1:]
    sens: dict[str, dict] = {}
    for z, s in designs.items():
        amps, times = kernel_impulses([s])
        for plant_zeta, key in ((z, "mode_zeta_equals_design"), (ARM_ZETA, "mode_zeta_0.09")):
            if key == "mode_zeta_0.09" and plant_zeta == z:
                sens[str(z)][key] = sens[str(z)]["mode_zeta_equals_design"]
                continue
            v = residual_vibration(amps, times, ratio * ARM_F_HZ, plant_zeta)
            b5 = band_below(ratio, v, 1.0, 0.05)
            sens.setdefault(str(z), {})[key] = {
                "mode_zeta": plant_zeta,
                "V_at_design": float(residual_vibration(amps, times, ARM_F_HZ, plant_zeta)),
                "V_below_5pct_ratio_band": list(b5) if b5 else None,
                "V_below_5pct_width": (b5[1] - b5[0]) if b5 else None,
                "V_at_ratio": {f"{r:g}": float(residual_vibration(amps, times, r * ARM_F_HZ, plant_zeta)) for r in (0.8, 0.9, 1.1, 1.2)},
            }
    rep.results["arm_4p4hz"] = {"frequency_hz": ARM_F_HZ, "sample_rate_hz": ARM_FS_HZ, "designs": arm, "sensitivity": sens}
    return ratio, sens


def _arm_response_figure(rep: Report, designs: dict[float, StageDesign], f2: np.ndarray) -> None:
    """The 4.4 Hz designs' magnitude responses."""
    fig = new_figure(9.0, 4.0)
    ax1, ax2 = fig.subplots(1, 2)
    for (z, s), col in zip(designs.items(), ("tab:blue", "tab:orange")):
        mag = np.abs(frequency_response(f2, [s]))
        ax1.plot(f2, 20 * np.log10(np.maximum(mag, 1e-6)), color=col, label=f"design ζ = {z}")
        ax2.plot(f2, mag, color=col, label=f"design ζ = {z}")
    for ax in (ax1, ax2):
        ax.axvline(ARM_F_HZ, color="k", ls="--", lw=0.8)
        ax.grid(True, lw=0.3)
        ax.set_xlabel("frequency (Hz)")
    ax1.set_ylabel("|F| (dB)")
    ax1.set_ylim(-90, 5)
    ax1.set_title("0–100 Hz")
    ax2.set_xlim(0, 15)
    ax2.set_ylabel("|F|")
    ax2.set_title("0–15 Hz, linear")
    ax1.legend(fontsize=8)
    rep.figure(fig, "oatf_4p4hz_response.png", "OATF magnitude response for a 4.4 Hz mode at 200 Hz (Fig. 4.8); the dashed line is the design frequency.")


def _sensitivity_figure(rep: Report, designs: dict[float, StageDesign], ratio: np.ndarray) -> None:
    """Residual vibration against ω/ω_design of the two 4.4 Hz designs."""
    fig = new_figure(9.0, 4.0)
    axes = fig.subplots(1, 2, sharey=True)
    for ax, key, title in (
        (axes[0], "mode_zeta_equals_design", "mode damping = design damping"),
        (axes[1], "mode_zeta_0.09", "the arm's mode, ζ = 0.09"),
    ):
        for (z, s), col in zip(designs.items(), ("tab:blue", "tab:orange")):
            amps, times = kernel_impulses([s])
            plant_zeta = z if key == "mode_zeta_equals_design" else ARM_ZETA
            ax.plot(ratio, 100 * residual_vibration(amps, times, ratio * ARM_F_HZ, plant_zeta), color=col, label=f"design ζ = {z}")
        ax.axhline(5, color="0.5", ls=":", lw=0.8)
        ax.set_xlabel("ω / ω_design")
        ax.set_title(title, fontsize=9)
        ax.grid(True, lw=0.3)
    axes[0].set_ylabel("residual vibration V (%)")
    axes[0].set_ylim(0, 120)
    axes[0].legend(fontsize=8)
    rep.figure(fig, "oatf_sensitivity.png", "Residual vibration V(ω/ω_design) of the two 4.4 Hz designs; dotted: 5 %.")


def _sensitivity_table(rep: Report, sens: dict[str, dict]) -> None:
    """The table of sensitivity to the design frequency."""
    srows = []
    for z in DESIGN_ZETAS:
        for key in ("mode_zeta_equals_design", "mode_zeta_0.09"):
            d = sens[str(z)][key]
            if key == "mode_zeta_0.09" and d["mode_zeta"] == z:
                continue
            label = d["mode_zeta"]
            b = d["V_below_5pct_ratio_band"]
            srows.append(
                [
                    z,
                    label,
                    100 * d["V_at_design"],
                    f"{b[0]:.3f}–{b[1]:.3f}" if b else "never",
                    d["V_below_5pct_width"],
                    100 * d["V_at_ratio"]["0.9"],
                    100 * d["V_at_ratio"]["1.1"],
                ]
            )
    rep.table(
        ["design ζ", "mode ζ", "V at ω_design (%)", "V ≤ 5 % for ω/ω_design in", "width", "V at 0.9 (%)", "V at 1.1 (%)"],
        srows,
        caption="Sensitivity to the design frequency",
    )


def _checks(rep: Report) -> None:
    """The checks and the comparison with the thesis, from the results."""
    ex, arm4 = rep.results["example_51hz"], rep.results["arm_4p4hz"]
    at51, f_cont, rv = ex["abs_F_at_51hz"], ex["notch_continuous_hz"], ex["residual_vibration_at_51hz"]
    arm, sens = arm4["designs"], arm4["sensitivity"]
    rep.check("discrete design: |F(51 Hz)| ≈ 0", at51["discrete"] < 1e-9, f"|F(51 Hz)| = {at51['discrete']:.2e}")
    rep.check(
        "continuous-delay design misses 51 Hz",
        at51["continuous"] > 0.05 and abs(f_cont - EXAMPLE_F_HZ) > 1.0,
        f"|F(51 Hz)| = {at51['continuous']:.4f}, its notch at {f_cont:.2f} Hz",
    )
    rep.check(
        "discrete design cancels a damped 51 Hz mode (V = 0)",
        all(r["discrete"] < 1e-9 for r in rv.values()),
        ", ".join(f"ζ {z}: V = {r['discrete']:.1e}" for z, r in rv.items()),
    )
    rep.check(
        "4.4 Hz designs have a zero on the design pole",
        all(a["abs_F_at_pole"] < 1e-9 for a in arm.values()),
        ", ".join(f"ζ {a['design_zeta']}: |F(e^(s·Ts))| = {a['abs_F_at_pole']:.1e}" for a in arm.values()),
    )
    w09 = sens["0.09"]["mode_zeta_0.09"]["V_below_5pct_width"] or 0.0
    w01 = sens["0.01"]["mode_zeta_0.09"]["V_below_5pct_width"] or 0.0
    rep.thesis(
        "The discrete filter must take its coefficients from n1·Ts: designing from the continuous delay misplaces the zero (51 Hz at 500 Hz).",
        f"From n1·Ts: |F(51 Hz)| = {at51['discrete']:.1e}. From T1: |F(51 Hz)| = {at51['continuous']:.3f} and its notch sits at {f_cont:.2f} Hz "
        f"({100 * (f_cont / EXAMPLE_F_HZ - 1):+.1f} %); it leaves V = {100 * rv['0.09']['continuous']:.1f} % of a ζ = 0.09 mode's vibration.",
        at51["discrete"] < 1e-9 and at51["continuous"] > 0.05,
    )
    zd = [z["frequency_hz"] for z in ex["zeros_discrete"] if abs(z["radius"] - 1) < 1e-6]
    rep.thesis(
        "The correct discrete design always has a zero at the design frequency; its higher zeros need not sit at integer multiples.",
        "Unit-circle zeros of the n1·Ts design: " + ", ".join(f"{f:.2f}" for f in zd) + " Hz.",
        any(abs(f - EXAMPLE_F_HZ) < 1e-6 for f in zd) and any(abs(f / EXAMPLE_F_HZ - round(f / EXAMPLE_F_HZ)) > 0.05 for f in zd if f > 1.0),
    )
    rep.thesis(
        "§4.4: OATF damping 0.01 gives narrower zeros, more sensitive to the design frequency (Fig. 4.8).",
        f"On the arm's ζ = 0.09 mode, V ≤ 5 % over a ω/ω_design width of {w09:.3f} for design ζ 0.09 and {w01:.3f} for 0.01"
        f" (V at the design frequency {100 * sens['0.01']['mode_zeta_0.09']['V_at_design']:.1f} % for the 0.01 design, because its damping is wrong). "
        f"|F| ≤ −20 dB over {arm['0.09']['band_below_minus20db_width_hz'] or 0:.2f} Hz (ζ 0.09) and {arm['0.01']['band_below_minus20db_width_hz'] or 0:.2f} Hz (ζ 0.01).",
        w01 < w09,
    )
