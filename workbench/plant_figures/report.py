"""Figures and numbers for docs/plant-model.md.

``ralf-hil plant report [--out docs/img]`` draws:

* ``plant-modal-map.png``: first and second natural frequency over the
  workspace, without and with the payload, the inspection loop overlaid;
* ``plant-loop.png``: along one lap of the loop (5 in/s), the true modal
  frequencies, and the deflections of a closed-loop run with a plain PI
  joint controller at the thesis's gains;
* ``plant-frf.png``: the four transfer functions (valve volts to link
  deflection) at the apex of the loop and at its bottom: the split pair
  against the well-separated modes;

and prints the measured numbers quoted in the docs as JSON.  The closed
loop here is the plant's own check (no CAN, no OATF), not the project's
controller.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from controller.metrics import rms_costs
from plant_emulator.model import kinematics as kin
from plant_emulator.model.arm import PlantConfig, RalfArm
from plant_emulator.model.calibration import APEX_RAD, BOTTOM_RAD, metrics
from plant_emulator.model.modes import frequency_response, modal_parameters

FS = 200.0
KP = np.array([7.5, 6.25])
"""Thesis §4: proportional gains, V/rad."""
KI = np.array([5.0, 4.166])
"""Thesis §4: integral gains, read here as V/(rad s)."""
INTEGRATOR_WINDOW_RAD = 0.04
KV = PlantConfig().valve_gain_in_per_s_per_v


@dataclass
class LoopRun:
    t: npt.NDArray[np.float64]
    theta_ref: npt.NDArray[np.float64]
    theta: npt.NDArray[np.float64]
    volts: npt.NDArray[np.float64]
    defl_true: npt.NDArray[np.float64]
    defl_read: npt.NDArray[np.float64]
    freqs: npt.NDArray[np.float64]
    hard_stops: int


def blend_setpoints(ref: npt.NDArray[np.float64], window_s: float) -> npt.NDArray[np.float64]:
    """Joint set-points averaged over a centred window of ``window_s`` (an odd
    number of samples, ends held): each corner's velocity step becomes a ramp
    over the window, i.e. a bounded set-point acceleration."""
    half = int(round(window_s * FS / 2.0))
    if half <= 0:
        return ref
    kernel = np.ones(2 * half + 1) / (2 * half + 1)
    pad = np.pad(ref, ((half, half), (0, 0)), mode="edge")
    return np.stack([np.convolve(pad[:, j], kernel, mode="valid") for j in range(ref.shape[1])], axis=1)


def closed_loop(
    payload: bool = False,
    laps: int = 1,
    seed: int = 0,
    speed_in_s: float | None = None,
    *,
    config: PlantConfig | None = None,
    blend_s: float = 0.0,
    integrator_window_rad: float = INTEGRATOR_WINDOW_RAD,
    shape_volts: Callable[[npt.NDArray[np.float64]], npt.NDArray[np.float64]] | None = None,
) -> LoopRun:
    """The inspection loop under PI joint control at 200 Hz, plant in lockstep.

    The keyword-only hooks serve ``speed_probe`` (what-if variants of the loop):
    ``config`` replaces ``PlantConfig(seed, payload)``, ``blend_s`` smooths the
    set-points (:func:`blend_setpoints`), ``integrator_window_rad`` = 0 turns the
    integrator off, ``shape_volts`` maps the PI's output before the valves."""
    tr = kin.sample_trajectory(dt_s=1.0 / FS, speed_in_s=speed_in_s)
    ref = blend_setpoints(np.tile(np.stack([tr.theta1_rad, tr.theta2_rad], axis=1), (laps, 1)), blend_s)
    arm = RalfArm(config if config is not None else PlantConfig(seed=seed, payload_attached=payload))
    n = ref.shape[0]
    integ = np.zeros(2)
    out = {k: np.empty((n, 2)) for k in ("theta", "volts", "true", "read", "f")}
    for k in range(n):
        v = arm.sample().values_in
        th = np.array([kin.CYLINDER1.angle(v[0]), kin.CYLINDER2.angle(v[1])])
        err = ref[k] - th
        integ = np.where(np.abs(err) < integrator_window_rad, integ * (1 - 1e-4) + err / FS, integ)
        u = KP * err + KI * integ
        if shape_volts is not None:
            u = shape_volts(u)
        arm.set_valve_voltages(u)
        t = arm.truth()
        out["theta"][k] = t.theta_rad
        out["volts"][k] = u
        out["true"][k] = t.deflections_in
        out["read"][k] = v[2:]
        out["f"][k] = t.modal_frequencies_hz
        arm.advance(1.0 / FS)
    return LoopRun(
        t=np.arange(n) / FS,
        theta_ref=ref,
        theta=out["theta"],
        volts=out["volts"],
        defl_true=out["true"],
        defl_read=out["read"],
        freqs=out["f"],
        hard_stops=arm.hard_stop_count,
    )


def loop_numbers(run: LoopRun) -> dict[str, float]:
    """Tracking, and which mode the trajectory excites near the apex."""
    import scipy.signal

    err = np.degrees(np.abs(run.theta_ref - run.theta))
    tr = kin.sample_trajectory(dt_s=1.0 / FS)
    # the top row of the loop (theta2 < 32 deg, after the first pause), where the modes are split
    top = (np.tile(tr.theta2_rad, len(run.t) // len(tr.t_s)) < math.radians(32.0)) & (run.t > 11.0)
    x = run.defl_true[top] - run.defl_true[top].mean(axis=0)
    f, p = scipy.signal.welch(x, FS, nperseg=512, axis=0)
    f1, f2 = np.median(run.freqs[top], axis=0)
    near = lambda fc: (f > 0.93 * fc) & (f < 1.07 * fc)  # noqa: E731
    p_sum = p.sum(axis=1)
    return {
        "max_tracking_error_deg": float(err.max()),
        "rms_tracking_error_deg": float(np.sqrt((err**2).mean())),
        "max_abs_volts": float(np.abs(run.volts).max()),
        "deflection_std_in_link1": float(run.defl_true[:, 0].std()),
        "deflection_std_in_link2": float(run.defl_true[:, 1].std()),
        "top_row_f1_hz": float(f1),
        "top_row_f2_hz": float(f2),
        "top_row_psd_at_f1_over_f2": float(p_sum[near(f1)].mean() / p_sum[near(f2)].mean()),
        "hard_stops": float(run.hard_stops),
        "loop_crossover_rad_s_joint1": float(KP[0] * KV[0] / np.mean(kin.CYLINDER1.lever_in_per_rad(tr.theta1_rad))),
        "loop_crossover_rad_s_joint2": float(KP[1] * KV[1] / np.mean(kin.CYLINDER2.lever_in_per_rad(tr.theta2_rad))),
    }


THESIS_UNFILTERED: dict[tuple[float, bool], tuple[float, float, float, float]] = {
    (5.0, True): (0.317, 0.359, 4.807, 5.354),
    (5.0, False): (0.262, 0.273, 3.833, 3.573),
    (4.0, True): (0.426, 0.478, 6.413, 7.109),
    (4.0, False): (0.358, 0.353, 5.177, 4.613),
}
"""Thesis Table 4-1, row (a): RMS deflection velocity (in/s) and acceleration (in/s^2), link 1, link 2."""


def unfiltered_costs(seed: int = 0) -> dict[str, dict[str, object]]:
    """The battery's unfiltered runs (a) in the cheapest faithful form: one lap
    under PI, the deflections as the A/D reads them, the §4.2.1 costs
    (``controller.metrics``), against the thesis's Table 4-1 row (a)."""
    out: dict[str, dict[str, object]] = {}
    for (speed, payload), thesis in THESIS_UNFILTERED.items():
        run = closed_loop(payload=payload, seed=seed, speed_in_s=speed)
        c = rms_costs(run.defl_read, 1.0 / FS)
        got = [*c.velocity_rms.tolist(), *c.acceleration_rms.tolist()]
        out[f"{speed:g}in_s_{'payload' if payload else 'nopayload'}"] = {
            "velocity_in_s": got[:2],
            "acceleration_in_s2": got[2:],
            "thesis": list(thesis),
            "ratio_to_thesis": [g / t for g, t in zip(got, thesis, strict=True)],
            "mean_true_f1_hz": float(run.freqs[:, 0].mean()),
        }
    return out


def _workspace_maps(axs, fig) -> None:
    """Rows: without / with payload. Columns: f1 and f2 over the joint-space
    workspace (the loop overlaid), and a cut at theta1 = 85 deg."""
    n1, n2 = 81, 221
    t1, t2 = np.meshgrid(np.linspace(*kin.THETA1_LIMITS_RAD, n1), np.linspace(*kin.THETA2_LIMITS_RAD, n2))
    tr = kin.sample_trajectory(dt_s=0.05)
    cut = np.linspace(*kin.THETA2_LIMITS_RAD, 400)
    ranges = ((1.5, 6.0), (4.0, 10.0))
    for row, payload in enumerate((False, True)):
        f, _ = modal_parameters(t1, t2, payload)
        for col in range(2):
            ax = axs[row, col]
            lo, hi = ranges[col]
            levels = np.linspace(lo, hi, 37)
            cs = ax.contourf(np.degrees(t1), np.degrees(t2), np.clip(f[..., col], lo, hi), levels=levels, cmap="viridis")
            cl = ax.contour(np.degrees(t1), np.degrees(t2), f[..., col], levels=np.arange(2.0, 10.1, 0.5), colors="k", linewidths=0.4)
            ax.clabel(cl, fontsize=6, fmt="%.1f")
            ax.plot(np.degrees(tr.theta1_rad), np.degrees(tr.theta2_rad), "w-", lw=1.6)
            ax.plot(np.degrees(tr.theta1_rad[:1]), np.degrees(tr.theta2_rad[:1]), "wo", ms=4)
            ax.set_title(f"f{col + 1} (Hz), {'with' if payload else 'without'} payload", fontsize=9)
            ax.set_xlabel("theta1 (deg)")
            ax.set_ylabel("theta2 (deg)  [top of workspace: 10 deg]")
            fig.colorbar(cs, ax=ax, shrink=0.85, ticks=np.arange(np.ceil(lo), hi + 0.01, 1.0))
        ax = axs[row, 2]
        fc, _ = modal_parameters(math.radians(85.0), cut, payload)
        ax.plot(np.degrees(cut), fc[:, 0], "C0", label="f1")
        ax.plot(np.degrees(cut), fc[:, 1], "C1", label="f2")
        ax.axvspan(np.degrees(tr.theta2_rad.min()), np.degrees(tr.theta2_rad.max()), color="0.9", label="loop's theta2 range")
        ax.axvline(math.degrees(APEX_RAD[1]), color="k", ls=":", lw=0.8, label="apex")
        ax.set_xlabel("theta2 (deg), theta1 = 85 deg")
        ax.set_ylabel("Hz")
        ax.set_ylim(0, 10.5)
        ax.set_title(f"cut {'with' if payload else 'without'} payload: veering near the top", fontsize=9)
        ax.legend(fontsize=7)


def make_figures(out: Path) -> dict[str, object]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    numbers: dict[str, object] = {"calibration": asdict(metrics())}

    fig, axs = plt.subplots(2, 3, figsize=(15, 8.5))
    _workspace_maps(axs, fig)
    fig.suptitle("RALF plant: natural frequencies over the joint-space workspace (white: inspection loop, dot: its start)")
    fig.tight_layout()
    fig.savefig(out / "plant-modal-map.png", dpi=110)
    plt.close(fig)

    runs = {p: closed_loop(payload=p) for p in (False, True)}
    numbers["closed_loop"] = {("payload" if p else "no_payload"): loop_numbers(r) for p, r in runs.items()}
    fig, axs = plt.subplots(4, 1, figsize=(11, 11), sharex=True)
    r0, r1 = runs[False], runs[True]
    axs[0].plot(r0.t, r0.freqs[:, 0], "C0", label="f1, no payload")
    axs[0].plot(r0.t, r0.freqs[:, 1], "C0--", label="f2, no payload")
    axs[0].plot(r1.t, r1.freqs[:, 0], "C3", label="f1, payload")
    axs[0].plot(r1.t, r1.freqs[:, 1], "C3--", label="f2, payload")
    axs[0].axhline(r0.freqs[:, 0].mean(), color="C0", lw=0.6)
    axs[0].axhline(r1.freqs[:, 0].mean(), color="C3", lw=0.6)
    axs[0].set_ylabel("true frequency (Hz)")
    axs[0].legend(ncol=4, fontsize=8)
    axs[1].plot(r0.t, np.degrees(r0.theta))
    axs[1].set_ylabel("theta1, theta2 (deg)")
    axs[2].plot(r0.t, r0.defl_read[:, 0], "C0", lw=0.6, label="link 1, as read (sensor zero: middle of the loop's static sag)")
    axs[2].plot(r0.t, r0.defl_read[:, 1], "C1", lw=0.6, label="link 2, as read")
    axs[2].set_ylabel("deflection, no payload (in)")
    axs[2].legend(fontsize=8)
    axs[3].plot(r1.t, r1.defl_read[:, 0], "C0", lw=0.6, label="link 1")
    axs[3].plot(r1.t, r1.defl_read[:, 1], "C1", lw=0.6, label="link 2")
    axs[3].set_ylabel("deflection, payload (in)")
    axs[3].set_xlabel("time (s), one lap at 5 in/s, PI joint control (Kp 7.5/6.25 V/rad)")
    axs[3].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "plant-loop.png", dpi=110)
    plt.close(fig)

    fr = np.linspace(0.5, 15.0, 1500)
    fig, axs = plt.subplots(2, 2, figsize=(11, 7.5), sharex=True)
    frf: dict[str, object] = {}
    for col, (name, th) in enumerate((("apex", APEX_RAD), ("bottom", BOTTOM_RAD))):
        for row, payload in enumerate((False, True)):
            ax = axs[row, col]
            H = frequency_response(*th, fr, payload)
            fm, _ = modal_parameters(*th, payload)
            for i in range(2):
                for j in range(2):
                    ax.semilogy(fr, np.abs(H[:, i, j]), label=f"H{i + 1}{j + 1}")
            ax.semilogy(fr, np.abs(H.mean(axis=(1, 2))), "k", lw=1.6, label="H_tot")
            for fmode in fm:
                ax.axvline(fmode, color="grey", ls=":")
            ax.set_title(
                f"{name} (theta = {math.degrees(th[0]):.1f}, {math.degrees(th[1]):.1f} deg), "
                f"{'payload' if payload else 'no payload'}: {fm[0]:.2f} / {fm[1]:.2f} Hz",
                fontsize=9,
            )
            ax.set_ylabel("|H| (in/V)")
            Hm = frequency_response(*th, fm, payload)
            frf[f"{name}_{'payload' if payload else 'no_payload'}"] = {
                "f_hz": [float(x) for x in fm],
                "abs_Hij_at_f1": [float(x) for x in np.abs(Hm[0]).ravel()],
                "abs_Hij_at_f2": [float(x) for x in np.abs(Hm[1]).ravel()],
                "abs_Htot_at_f1_f2": [float(abs(Hm[0].mean())), float(abs(Hm[1].mean()))],
            }
    axs[0, 0].legend(fontsize=8, ncol=5)
    for ax in axs[1]:
        ax.set_xlabel("frequency (Hz)")
    fig.suptitle("Valve volts to tip deflection (linearised plant): H_ij from valve i to link j")
    fig.tight_layout()
    fig.savefig(out / "plant-frf.png", dpi=110)
    plt.close(fig)
    numbers["frf"] = frf
    numbers["unfiltered_battery"] = unfiltered_costs()
    return numbers
