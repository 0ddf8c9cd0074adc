"""``ralf-hil plot RUN.mcap``: the figures a user wants after a run, as PNGs.

* ``deflections.png`` -- the two links' tip deflections: the plant's truth
  and what the controller measured (the batches' outputs);
* ``joints.png`` -- joint tracking: true joint angles against the
  trajectory's set-points (rebuilt from the recorded controller settings),
  and the tracking error;
* ``modes.png`` -- identified first and second modes (the DSP's interrupts)
  against the plant's true modal frequencies;
* ``tf_spectrogram.png`` -- |H_tot| of every TF download over time
  (``controller/tf``), the true modes drawn over it;
* ``timing.png`` -- histograms of the SYNC period and SYNC -> TPDO1 as the
  tap saw them on the bus, batch -> interrupt, the DSP's compute time, and
  the controller's TET and SYNC lateness percentiles over the run.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from workbench.experiments.report import new_figure
from workbench.recording.reader import Recording

FIGURES = ("deflections.png", "joints.png", "modes.png", "tf_spectrogram.png", "timing.png")


def _save(fig: Figure, out: Path, name: str) -> Path:
    path = out / name
    fig.savefig(path)
    return path


def _caption(fig: Figure, text: str) -> None:
    """One line under the figure: what it shows and what to look for."""
    fig.supxlabel(text, fontsize=7.5, color="0.25")


def _history_s(rec: Recording) -> float:
    """How long the identifier waits for its first estimate: one full history, N / fs (the recorded DSP settings)."""
    dsp = rec.settings("dsp")
    try:
        return float(dsp.get("fft_width", 2048)) / float(dsp.get("sample_rate_hz", 200.0) or 200.0)
    except (TypeError, ValueError):
        return 2048 / 200.0


def _no_data(ax: object, what: str) -> None:
    ax.text(0.5, 0.5, f"no {what} in this recording", ha="center", va="center", transform=ax.transAxes)  # type: ignore[attr-defined]


def plot_deflections(rec: Recording, out: Path) -> Path:
    fig = new_figure(8, 5)
    axes = fig.subplots(2, 1, sharex=True)
    truth = rec.truth()
    batches = rec.data("dsp/batch")
    for link, ax in enumerate(axes):
        if batches:
            t = np.concatenate([b["sim_time_s"] + np.arange(b["n_samples"]) / b["sample_rate_hz"] for b in batches])
            d = np.concatenate([np.asarray(b["outputs"][link]) for b in batches])
            ax.plot(t, d, lw=0.6, color="tab:blue", label="measured (controller, 200 Hz)")
        if truth:
            ax.plot(truth["sim_time_s"], truth["deflections_in"][:, link], lw=1.0, color="tab:red", label="true (plant)")
        if not batches and not truth:
            _no_data(ax, "deflections")
        ax.set_ylabel(f"link {link + 1} tip deflection (in)")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("simulated time (s)")
    fig.suptitle("Tip deflections")
    _caption(fig, "Measured (blue) against true (red) tip deflection per link: the two should overlie; the ringing after each corner is the arm's first mode.")
    return _save(fig, out, "deflections.png")


def _setpoints(rec: Recording, t: np.ndarray) -> np.ndarray | None:
    """Trajectory theta set-points at simulated times ``t`` from the recorded controller settings."""
    from controller.config import build_trajectory
    from protocol.settings import ACCESS_FIELDS, ControllerSettings, upgrade_recorded

    values = {k: v for k, v in upgrade_recorded(rec.settings("controller")).items() if k in ControllerSettings.model_fields and k not in ACCESS_FIELDS}
    try:
        settings = ControllerSettings.model_validate(values)
        traj = build_trajectory(settings)
    except Exception:  # a recording without (valid) controller settings: no set-points
        return None
    theta = traj.joints.theta
    ticks = np.round(t / settings.sample_period_s).astype(int) % len(theta)
    return theta[ticks]


def plot_joints(rec: Recording, out: Path) -> Path:
    fig = new_figure(8, 6)
    axes = fig.subplots(3, 1, sharex=True)
    truth = rec.truth()
    if not truth:
        for ax in axes:
            _no_data(ax, "ground truth")
        return _save(fig, out, "joints.png")
    t = truth["sim_time_s"]
    th = np.degrees(truth["theta_rad"])
    # The plant samples one period after the controller's tick: tick k sees the plant at (k+1) Ts.
    ts = 1.0 / float(rec.settings("controller").get("sample_rate_hz", 200.0) or 200.0)
    sp = _setpoints(rec, t - ts)
    for j in range(2):
        axes[j].plot(t, th[:, j], color="tab:red", lw=1.0, label="true")
        if sp is not None:
            axes[j].plot(t, np.degrees(sp[:, j]), color="k", lw=0.8, ls="--", label="set-point")
            axes[2].plot(t, th[:, j] - np.degrees(sp[:, j]), lw=0.8, label=f"θ{j + 1}")
        axes[j].set_ylabel(f"θ{j + 1} (deg)")
        axes[j].grid(alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[2].set_ylabel("tracking error (deg)")
    if sp is None:
        _no_data(axes[2], "controller settings (set-points)")
    else:
        axes[2].legend(loc="upper right", fontsize=8)
    axes[2].grid(alpha=0.3)
    axes[2].set_xlabel("simulated time (s)")
    fig.suptitle("Joint tracking")
    _caption(fig, "True joint angles against the set-points, and their difference: look for a small, steady tracking error with no drift.")
    return _save(fig, out, "joints.png")


def plot_modes(rec: Recording, out: Path) -> Path:
    fig = new_figure(8, 4.5)
    ax = fig.add_subplot()
    truth = rec.truth()
    if truth:
        for m in range(truth["modal_frequencies_hz"].shape[1]):
            ax.plot(
                truth["sim_time_s"],
                truth["modal_frequencies_hz"][:, m],
                color="k",
                lw=1.0 if m == 0 else 0.7,
                ls="-" if m == 0 else ":",
                label=f"true mode {m + 1}",
            )
    irqs = rec.interrupts()
    t = np.array([i["sim_time_s"] for i in irqs], dtype=float)
    # each interrupt's first two poles, lower first: the colours follow the lower and upper mode, not the DSP's ranking
    f = np.full((len(irqs), 2), np.nan)
    for row, irq in zip(f, irqs):
        poles = sorted(float(p["frequency_hz"]) for p in irq["poles"][:2])
        row[: len(poles)] = poles
    for k, (color, label) in enumerate((("tab:blue", "identified, lower pole"), ("tab:orange", "identified, upper pole"))):
        if np.isfinite(f[:, k]).any():
            ax.plot(t, f[:, k], ".", ms=3, color=color, label=label)
    estimated = t[np.isfinite(f).any(axis=1)] if irqs else t
    first = float(estimated[0]) if estimated.size else None
    if first is not None and first > 0:
        ax.axvspan(0.0, first, color="0.92", lw=0)
        ax.text(
            first / 2,
            0.03,
            f"no estimate yet:\nfirst full history\n(N/fs = {_history_s(rec):.2f} s)",
            ha="center",
            va="bottom",
            fontsize=7,
            transform=ax.get_xaxis_transform(),
        )
    if not irqs and not truth:
        _no_data(ax, "modes")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("frequency (Hz)")
    ax.set_ylim(0, None)
    ax.set_xlim(0, None)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Identified vs true modes")
    _caption(fig, "The DSP's two identified poles (dots) against the plant's true modes (lines): the dots should follow the lines, a few seconds late.")
    return _save(fig, out, "modes.png")


def plot_tf_spectrogram(rec: Recording, out: Path, name: str = "Htot") -> Path:
    fig = new_figure(8, 4.5)
    ax = fig.add_subplot()
    snaps = rec.tf_downloads()
    if snaps:
        n = len(snaps[-1]["freqs_hz"])
        snaps = [s for s in snaps if len(s["freqs_hz"]) == n]
        f = np.asarray(snaps[-1]["freqs_hz"], dtype=float)
        t = np.array([s["sim_time_s"] for s in snaps], dtype=float)
        mag = np.array([s["estimates"][name]["magnitude"] for s in snaps], dtype=float)
        valid = np.array([s["valid"] for s in snaps], dtype=bool)
        # Bins the DSP marks invalid (no excitation, history not full yet) carry 0: not drawn.
        db = np.where(valid & (mag > 0), 20 * np.log10(np.where(mag > 0, mag, 1.0)), np.nan)
        # a download holds the estimate of the data before it: its column spans the interval up to its time
        step = float(np.median(np.diff(t))) if t.size > 1 else float(t[0]) or 1.0
        edges_t = np.concatenate([[max(0.0, t[0] - step)], t])
        df = f[1] - f[0] if f.size > 1 else 1.0
        edges_f = np.concatenate([f - df / 2, [f[-1] + df / 2]])
        mesh = ax.pcolormesh(
            edges_t,
            edges_f,
            db.T,
            shading="flat",
            cmap="viridis",
            vmin=float(np.nanpercentile(db, 5)) if np.isfinite(db).any() else None,
            vmax=float(np.nanmax(db)) if np.isfinite(db).any() else None,
        )
        fig.colorbar(mesh, ax=ax, label=f"|{name}| (dB)")
        truth = rec.truth()
        if truth:
            for m in range(truth["modal_frequencies_hz"].shape[1]):
                ax.plot(truth["sim_time_s"], truth["modal_frequencies_hz"][:, m], color="tab:red", lw=0.8, ls="--")
        ax.set_ylim(0, min(20.0, float(f[-1])))
        ax.set_xlim(0.0, max(float(edges_t[-1]), float(truth["sim_time_s"][-1]) if truth else 0.0))
        with_estimate = int(np.isfinite(db).any(axis=1).sum())
        title = f"TF downloads: |{name}| over time (dashed: true modes), {with_estimate} of {len(snaps)} downloads with an estimate"
    else:
        _no_data(ax, "TF downloads")
        title = f"TF downloads: |{name}| over time"
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("frequency (Hz)")
    ax.set_title(title, fontsize=10)
    _caption(
        fig,
        f"Each column: the downloaded estimate, drawn over the interval before its download; blank until the first full history (N/fs = {_history_s(rec):.2f} s)."
        "\nLook for the bright ridge on the dashed true modes.",
    )
    return _save(fig, out, "tf_spectrogram.png")


def _hist(ax: object, values_ms: np.ndarray, title: str) -> None:
    if values_ms.size == 0:
        _no_data(ax, title)
    else:
        ax.hist(values_ms, bins=60, color="tab:blue")  # type: ignore[attr-defined]
        p50, p99 = np.percentile(values_ms, [50, 99])
        title += f"\np50 {p50:.2f}, p99 {p99:.2f}, max {values_ms.max():.2f} ms\n(n={values_ms.size})"
        ax.set_yscale("log")  # type: ignore[attr-defined]
    ax.set_title(title, fontsize=8)  # type: ignore[attr-defined]
    ax.set_xlabel("ms")  # type: ignore[attr-defined]


def timing_series(rec: Recording) -> dict[str, np.ndarray]:
    """The timing figures a recording gives (ms): SYNC period and SYNC -> TPDO1
    at the tap, batch -> interrupt, DSP compute."""
    sync_t: list[float] = []
    sync_to_tpdo: list[float] = []
    last_sync: float | None = None
    for fr in rec.can_frames():
        if fr["frame"] == "sync":
            sync_t.append(fr["wall_time_s"])
            last_sync = fr["wall_time_s"]
        elif fr["frame"] == "tpdo1" and last_sync is not None:
            sync_to_tpdo.append(fr["wall_time_s"] - last_sync)
            last_sync = None
    sent = {b["seq"]: b["wall_time_s"] for b in rec.data("dsp/batch")}
    irq_times = {m.data["batch_seq"]: m.log_time_ns * 1e-9 for m in rec.iter("dsp/interrupt")}
    b2i = [irq_times[s] - w for s, w in sent.items() if s in irq_times]
    return {
        "sync_period_ms": np.diff(np.asarray(sync_t)) * 1e3,
        "sync_to_tpdo1_ms": np.asarray(sync_to_tpdo) * 1e3,
        "batch_to_interrupt_ms": np.asarray(b2i) * 1e3,
        "dsp_compute_ms": np.array([i["compute_time_s"] for i in rec.interrupts()], dtype=float) * 1e3,
    }


def plot_timing(rec: Recording, out: Path) -> Path:
    fig = new_figure(10, 6.5)
    axes = fig.subplots(2, 3)
    series = timing_series(rec)
    _hist(axes[0, 0], series["sync_period_ms"], "SYNC period (tap)")
    _hist(axes[0, 1], series["sync_to_tpdo1_ms"], "SYNC → TPDO1 (tap)")
    _hist(axes[0, 2], series["batch_to_interrupt_ms"], "batch → interrupt")
    _hist(axes[1, 0], series["dsp_compute_ms"], "DSP compute")
    health = rec.data("health/controller")
    ax = axes[1, 1]
    if health:
        t = np.array([h["sim_time_s"] for h in health])
        for lname, label in (("tet", "TET"), ("sync_jitter", "SYNC lateness")):
            for p, ls in (("p50", "-"), ("p99", "--")):
                v = np.array([h["latencies"].get(lname, {}).get(p, np.nan) for h in health], dtype=float) * 1e3
                ax.plot(t, v, ls=ls, label=f"{label} {p}")
        ax.legend(fontsize=7)
        ax.set_xlabel("simulated time (s)")
        ax.set_ylabel("ms (cumulative percentiles)")
    else:
        _no_data(ax, "controller health")
    ax.set_title("controller TET and SYNC lateness", fontsize=9)
    ax = axes[1, 2]
    if health:
        last = health[-1]["counters"]
        names = ["overruns", "deadline_misses", "samples_dropped", "periods_skipped", "tf_downloads"]
        ax.barh(names, [last.get(n, 0) for n in names], color="tab:gray")
        ax.set_title("controller counters at the end", fontsize=9)
    else:
        _no_data(ax, "controller health")
    fig.suptitle("Timing")
    _caption(fig, "Timing as the bus and the services saw it: look for narrow histograms at the nominal period and zero overruns and deadline misses.")
    return _save(fig, out, "timing.png")


def plot_all(path: str | Path, out_dir: str | Path) -> list[Path]:
    """Every figure of :data:`FIGURES` for the recording ``path`` into ``out_dir``."""
    rec = Recording.load(path)
    if rec.cut:
        print(f"{path}: {rec.cut}; plotting what it holds", file=sys.stderr)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [fn(rec, out) for fn in (plot_deflections, plot_joints, plot_modes, plot_tf_spectrogram, plot_timing)]
