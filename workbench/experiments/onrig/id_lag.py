"""``id-lag``: the identifier's delay after discontinuous changes, the payload released and picked up mid-run (thesis §5.3).

The thesis's future work asks for discontinuous parameter changes to measure
the identifier's delay precisely.  On the inspection loop the true first mode
itself moves by 20 % or more, so the arm follows instead a small closed loop
of irregular square teeth near its bottom-right corner (5 in/s, 24 s per lap;
``records/idlag_trajectory.json``) where the true first mode stays within
about 1.5 % with the payload and 0.6 % without it.  The 15.65 lb payload
starts attached; a stimulus on the plant's ``payload`` input (docs/stimulus.md)
releases it and picks it up again at ``EVENTS_S``: the first mode steps by
about +9.5 % (4.17 → 4.56 Hz) and back.  PI control only, OATF off; the same
sensor-noise seed for every run.

Per identifier setting (the thesis's N = 2048, α = 0.1, l = 20 against
shorter histories with smaller α, a large α, the Welch and transient-fit
ETFEs and the recursive ARX) the identified first pole in the controller's
record is compared with the plant's ground truth after every event
(:mod:`workbench.experiments.lib.identification_delay`: delays to 2 %, to stay
within 2 %, to half-way).  The best setting has the shortest median delay to
2 % among those that settle after every event.  The DSP's ARX is replayed
from its record with a reset at the true event, its change detector and
regime banks (:mod:`workbench.experiments.lib.arx_replay`), and run again with
a valve dither (:mod:`workbench.experiments.lib.dither_cost`).  ``--quick``:
N = 1024, α = 0.05 and the ARX, one release at 10 s, 26 s.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from controller.excitation import DitherConfig
from controller.trajectory import WaypointTrajectory, sample_trajectory
from dsp_service.identifier import IdentifierConfig
from plant_emulator.model.modes import modal_parameters
from workbench.campaign.rigs import map_rigs
from workbench.experiments.analysis import THESIS_BATCH_SIZE
from workbench.experiments.framework import ExperimentContext, experiment, run_layout
from workbench.experiments.lib.arx_replay import arx_replays
from workbench.experiments.lib.arx_replay_report import arx_replay_section, carried_bank_text
from workbench.experiments.lib.delay_figures import delay_bars_figure, tracks_figure
from workbench.experiments.lib.delay_tables import definitions_text, event_table, summary_table
from workbench.experiments.lib.dither_cost import dither_cost, whole_run_costs
from workbench.experiments.lib.dither_report import dither_section, dither_sent_checks
from workbench.experiments.lib.etfe_smoothing import smoothing_window
from workbench.experiments.lib.identification_delay import HOLD_S, MEDIAN_HALF_S, TOLERANCE, record_delays
from workbench.experiments.lib.teeth_loop import square_teeth_loop
from workbench.experiments.report import Report
from workbench.hil import RigSpec, RunRecord
from workbench.stimulus import Stimulus

__all__ = ["idlag_trajectory", "payload_stimulus", "run", "smoothing_window"]

FS_HZ = 200.0
SPEED = 5.0
EVENTS_S = (22.0, 42.0, 62.0, 82.0)
"""Payload released, picked up, released, picked up (the payload starts attached)."""
DURATION_S = 102.0
QUICK_EVENTS_S = (10.0,)
QUICK_DURATION_S = 26.0
Setting = tuple[int, float, str]
SETTINGS: tuple[Setting, ...] = (
    (2048, 0.1, "etfe"),
    (2048, 0.5, "etfe"),
    (1024, 0.1, "etfe"),
    (1024, 0.05, "etfe"),
    (512, 0.05, "etfe"),
    (512, 0.02, "etfe"),
    (2048, 0.1, "etfe-welch"),
    (1024, 0.1, "etfe-welch"),
    (2048, 0.1, "etfe-transient"),
    (2048, 0.1, "arx"),
)
"""(N, α, identifier); the first is the thesis's; ``arx``: the recursive ARX model's poles (N, α then only shape the downloads)."""
THESIS_SETTING = (2048, 0.1, "etfe")
QUICK_SETTINGS: tuple[Setting, ...] = ((1024, 0.05, "etfe"), (2048, 0.1, "arx"))
DITHER_AMPLITUDES_V = (0.003, 0.01, 0.03)
"""RMS (V) of the valve commands' multisine dither (``dither`` ``amplitude_v``, in its ``band_hz``) of the ARX runs
with persistent excitation; the D/A's step is 4.9 mV, the commands' own RMS on this loop ~0.05–0.06 V."""
QUICK_DITHER_AMPLITUDES_V = (0.01,)
GOAL_S = 1.0
"""The goal for a fast recursive identifier: within 2 % of the new first mode ≤ 1 s after the payload step. Reported as a
known limit (the first meeting with a regime and the dithered ARX do not reach it); the checks hold what the build reached."""
DITHER_REACHED_S = 3.7
"""The dithered ARX's best median delay to 2 % over the full run's four events (seed 0, co-simulated, 10 mV, change detector)."""
DITHER_MARGIN_S = 1.3
"""How far above :data:`DITHER_REACHED_S` the check allows before calling it a regression."""
REGIME_BANK = 4
"""Regimes the replayed ARX with a regime bank remembers (``arx_regime_bank``, docs/identification.md §5c)."""
CALIBRATION_SHIFT_S = 10.0
"""The calibration run's payload events come this much later than the run's (half their spacing): its regimes
are learned at other points of the loop, with another sensor-noise seed (docs/identification.md §5d)."""
_ARX = IdentifierConfig()
_DITHER = DitherConfig()
"""The dither's default band and period (the runs set only its amplitude)."""
ARX_FORGETTING = _ARX.arx_forgetting
"""The ARX identifier's forgetting factor per model sample (its default; memory 1/(1 − λ) model samples)."""
ARX_MEMORY_S = _ARX.arx_decimation / (_ARX.sample_rate_hz * (1.0 - ARX_FORGETTING))
"""The ARX model's memory in seconds (1/(1 − λ) samples at fs / D)."""
_TEETH = ((3.0, 4.0), (4.5, 2.5), (2.0, 5.0), (3.5, 3.0), (5.0, 4.5), (2.5, 2.0))
"""(width, height) in inches of each tooth, from a corner of the inspection loop along its bottom edge."""


def idlag_trajectory() -> WaypointTrajectory:
    """The small closed loop of irregular teeth (see the module doc)."""
    return square_teeth_loop(
        (-19.437, 196.612),
        (-0.985, -0.174),
        _TEETH,
        speed_in_per_s=SPEED,
        name="idlag_teeth",
        description="Irregular square teeth near the inspection loop's bottom-right corner: a nearly constant configuration with rich excitation (ralf-hil experiment id-lag)",
    )


def payload_stimulus(events: list[float]) -> Stimulus:
    """The payload (attached at the start) released at the first event, picked up at the second, and so on:
    a step to 0 on the plant's ``payload`` input from each odd-numbered event to the next."""
    stim = Stimulus()
    for release, pick_up in zip(events[::2], [*events[1::2], None]):
        stim.step("payload", 0.0, at_s=release, end_s=pick_up)
    return stim


def _name(n: int, alpha: float, method: str = "etfe") -> str:
    if method == "arx":
        return method
    base = f"n{n}_a{alpha:g}".replace(".", "p")
    return base if method == "etfe" else f"{base}_{method.replace('-', '_')}"


def _label(d: dict[str, Any]) -> str:
    if d.get("identifier", "etfe") == "arx":
        return f"ARX (λ {ARX_FORGETTING:g}, memory {ARX_MEMORY_S:.2g} s)"
    suffix = "" if d.get("identifier", "etfe") == "etfe" else f", {d['identifier']}"
    return f"N = {d['fft_width']}, α = {d['alpha']:g}{suffix}"


def _specs(duration: float, traj_path: Path, events: list[float], seed: int, settings: tuple[Setting, ...], amplitudes: tuple[float, ...]) -> list[RigSpec]:
    """One run per identifier setting (PI only along the loop of teeth, the payload events as a stimulus), the ARX
    run again with each dither amplitude, and the ARX's calibration run (another seed, its events later)."""
    ctrl = {
        "duration_s": duration,
        "tip_speed_in_s": SPEED,
        "trajectory": str(traj_path),
        "batch_size": THESIS_BATCH_SIZE,
        "tf_download_samples": 0,
        "oatf_mode": "off",
    }
    payload = tuple(payload_stimulus(events).profiles)
    specs = [
        RigSpec(
            _name(n, a, m),
            controller=ctrl,
            plant={"payload_attached": True, "seed": seed},
            dsp={"batch_size": THESIS_BATCH_SIZE, "fft_width": n, "alpha": a, "smoothing": {"window": smoothing_window(n)}, "identifier": m},
            label=f"N = {n}, α = {a:g}, l = {THESIS_BATCH_SIZE}, smoothing {smoothing_window(n)} bins" + ("" if m == "etfe" else f", {m}")
            if m != "arx"
            else f"recursive ARX (fs/{_ARX.arx_decimation}, na {_ARX.arx_na}, nb {_ARX.arx_nb}, Steiglitz–McBride, Huber k {_ARX.arx_huber_k:g}), "
            f"λ = {ARX_FORGETTING:g} per model sample (memory {ARX_MEMORY_S:.2g} s), l = {THESIS_BATCH_SIZE}",
            stimulus=payload,
        )
        for n, a, m in settings
    ]
    arx = next(sp for sp, (_n, _a, m) in zip(specs, settings) if m == "arx")
    dithered = [
        RigSpec(
            f"arx_dither_{1e3 * amp:g}mv".replace(".", "p"),
            controller={**arx.controller, "dither": {"amplitude_v": amp}},
            plant=arx.plant,
            dsp=arx.dsp,
            label=f"{arx.label}; valve dither {1e3 * amp:g} mV RMS",
            stimulus=payload,
        )
        for amp in amplitudes
    ]
    later = [at + CALIBRATION_SHIFT_S for at in events]
    calibration = RigSpec(
        "arx_calibration",
        controller=arx.controller,
        plant={**arx.plant, "seed": seed + 1},
        dsp=arx.dsp,
        label=f"{arx.label}; calibration run (sensor-noise seed {seed + 1}, payload events at " + ", ".join(f"{at:g}" for at in later) + " s)",
        stimulus=tuple(payload_stimulus(later).profiles),
    )
    return [*specs, *dithered, calibration]


def _settings_rows(settings: tuple[Setting, ...], runs: list[RunRecord], events: list[float]) -> dict[str, dict[str, Any]]:
    """The delays of every setting's run, with its settings."""
    rows: dict[str, dict[str, Any]] = {}
    for (n, a, m), r in zip(settings, runs):
        rows[_name(n, a, m)] = record_delays(r, events) | {
            "identifier": m,
            "fft_width": n,
            "alpha": a,
            "batch_size": THESIS_BATCH_SIZE,
            "smoothing_window": smoothing_window(n),
            "window_s": n / FS_HZ,
            "averaging_span_s": (n + THESIS_BATCH_SIZE * (1 / a - 1)) / FS_HZ,
            "run": r.run_facts(),
        }
    return rows


@experiment(
    "id-lag",
    section="§5.3 (future work)",
    description="Payload released and picked up mid-run on a small loop of teeth: delay of the identified first mode to within 2 % of the new truth, thesis settings vs shorter N / other α",
    needs_rig=True,
)
def run(ctx: ExperimentContext) -> Report:
    rep = ctx.report("Identification delay after releasing and picking up the payload")
    quick = ctx.quick
    events = list(QUICK_EVENTS_S) if quick else list(EVENTS_S)
    duration = QUICK_DURATION_S if quick else DURATION_S
    settings = QUICK_SETTINGS if quick else SETTINGS
    amplitudes = QUICK_DITHER_AMPLITUDES_V if quick else DITHER_AMPLITUDES_V
    traj = idlag_trajectory()
    traj_path = ctx.path("records/idlag_trajectory.json")
    traj_path.write_text(json.dumps(traj.model_dump(), indent=1) + "\n", encoding="utf-8")
    theta = sample_trajectory(traj, 1.0 / FS_HZ).joints.theta
    f_free = modal_parameters(theta[:, 0], theta[:, 1], False)[0][:, 0]
    f_load = modal_parameters(theta[:, 0], theta[:, 1], True)[0][:, 0]
    seed = int(ctx.rng("plant-seed").integers(0, 2**31 - 1))
    all_runs = map_rigs(ctx, _specs(duration, traj_path, events, seed, settings, amplitudes), in_process=quick, description="id-lag runs")
    runs, dither_runs, calibration = all_runs[: len(settings)], all_runs[len(settings) : -1], all_runs[-1]
    rows = _settings_rows(settings, runs, events)
    arx_run = next(r for (_n, _a, m), r in zip(settings, runs) if m == "arx")
    later = [at + CALIBRATION_SHIFT_S for at in events]
    arx = arx_replays(arx_run, events, FS_HZ, REGIME_BANK, calibration=calibration, calibration_events_s=later)
    base_cost = whole_run_costs(arx_run)
    dither = {
        "base": {"velocity_rms": base_cost["velocity_rms"], "acceleration_rms": base_cost["acceleration_rms"], "arx": arx},
        "runs": [dither_cost(arx_run, r, amp) | {"arx": arx_replays(r, events, FS_HZ, REGIME_BANK)} for amp, r in zip(amplitudes, dither_runs)],
    }
    thesis_key = _name(*THESIS_SETTING) if THESIS_SETTING in settings else _name(*settings[0])
    complete = {k: v for k, v in rows.items() if v["settled_events"] == len(events)}
    best_key = min(complete, key=lambda k: (complete[k]["median_settle_2pct_s"], complete[k]["median_rel_error_end"])) if complete else None
    lap_s = len(theta) / FS_HZ
    rep.results = {
        "trajectory": {
            "file": traj_path.name,
            "lap_s": lap_s,
            "true_f1_payload_hz": [float(f_load.min()), float(f_load.max())],
            "true_f1_free_hz": [float(f_free.min()), float(f_free.max())],
        },
        "events_s": events,
        "payload_stimulus": list(payload_stimulus(events).profiles),
        "duration_s": duration,
        "tolerance": TOLERANCE,
        "hold_s": HOLD_S,
        "median_half_window_s": MEDIAN_HALF_S,
        "settings": rows,
        "thesis_setting": thesis_key,
        "best_setting": best_key,
        "arx_replay": arx,
        "dither": dither,
    }
    th0 = rows[thesis_key]["events"][0]
    rep.heading("Runs")
    rep.text(
        f"{len(runs)} run(s) ({run_layout(ctx.mode, quick, parallel='two rigs at a time')}, {ctx.mode}), PI only, OATF off, along a small closed loop of "
        f"irregular square teeth ({lap_s:.1f} s per lap at {SPEED:g} in/s; `records/{traj_path.name}`), where the true first mode stays in "
        f"{f_load.min():.3f}–{f_load.max():.3f} Hz with the payload and {f_free.min():.3f}–{f_free.max():.3f} Hz without (model, along the set-points). "
        f"The payload starts attached and is released / picked up again at {', '.join(f'{e:g}' for e in events)} s (a stimulus on the plant's `payload` input); "
        f"the run ends at {duration:g} s. "
        f"Releasing it steps the true first mode by {th0['step_pct']:+.1f} % ({th0['true_before_hz']:.3f} → {th0['true_after_hz']:.3f} Hz). "
        + definitions_text()
    )
    _settings_tables(rep, rows, events, best_key)
    rep.figure(
        tracks_figure(runs, list(rows.values()), [_label(d) for d in rows.values()], events, TOLERANCE),
        "id_lag_tracks.png",
        "Identified first pole (dots), its centred running median (red), the true first mode (black) and the 2 % band around it, per setting; events at the dotted lines.",
    )
    _report_arx(rep, arx, events, quick)
    if dither["runs"]:
        dither_section(rep, dither, FS_HZ, _DITHER)
        _dither_checks(rep, dither, quick)
    rep.figure(
        delay_bars_figure(rows, [_tick(d) for d in rows.values()], len(events), TOLERANCE),
        "id_lag_delays.png",
        "Median delay to 2 % and to 50 % over the events, and the error at the end, per setting (∞: some event never settled).",
    )
    _checks_and_thesis(rep, rows, thesis_key, events, best_key, quick)
    rep.attach(traj_path, "the trajectory (way-points) of the runs")
    for r in runs:
        rep.attach(r.output(".npz"), f"run record: {r.label}")
    return rep


def _tick(d: dict[str, Any]) -> str:
    """A setting's label under the bars of the delay figure."""
    what = {"etfe": "", "etfe-welch": "\nWelch+fit", "etfe-transient": "\ntransient fit"}.get(d["identifier"], "")
    tick = f"N {d['fft_width']}\nα {d['alpha']:g}{what}" if d["identifier"] != "arx" else "ARX"
    return tick + ("\n(thesis)" if (d["fft_width"], d["alpha"], d["identifier"]) == THESIS_SETTING else "")


def _settings_tables(rep: Report, rows: dict[str, dict[str, Any]], events: list[float], best_key: str | None) -> None:
    """The table of delays per setting and the table of every event."""
    thesis = [" (thesis)" if (d["fft_width"], d["alpha"], d["identifier"]) == THESIS_SETTING else "" for d in rows.values()]
    labelled = [(_label(d) + t + (" **best**" if k == best_key else ""), d) for (k, d), t in zip(rows.items(), thesis)]
    before = [("window N/fs (s)", "window_s"), ("averaged span (s)", "averaging_span_s"), ("first estimate (s)", "first_estimate_s")]
    caption = "Per setting, over the events; averaged span = (N + l(1/α − 1)) / fs; error: median |f_id − f_true| / f_true over the last 8 s"
    summary_table(
        rep, labelled, len(events), before=before, after=[("median confidence", "median_confidence")], first_header="setting (l = 20)", caption=caption
    )
    event_table(rep, [(_label(d), d) for d in rows.values()])


def _report_arx(rep: Report, arx: dict[str, Any], events: list[float], quick: bool) -> None:
    """The ARX replayed from the record, and its checks: the replay is the DSP's, the regime banks' delays."""
    arx_replay_section(rep, arx, events, REGIME_BANK)
    rep.check(
        "the ARX replayed from the record reproduces the DSP's identified first pole",
        arx["max_difference_to_the_record_hz"] <= 1e-9,
        f"largest difference {arx['max_difference_to_the_record_hz']:.3g} Hz",
    )
    first = arx["regime_bank"]["events"][0]["settle_2pct_s"]
    seen = [e["settle_2pct_s"] for e in arx["regime_bank"]["events"][1:]]  # the first event leads into a regime the run has not shown yet
    if seen:
        rep.check(
            f"with the regime bank: within 2 % in ≤ {GOAL_S:g} s after the payload steps into a regime seen before "
            "(median over those events; the first event's regime is new to the model)",
            float(np.median(seen)) <= GOAL_S,
            "per event " + ", ".join(f"{x:.1f}" for x in seen) + f" s ({sum(x <= GOAL_S for x in seen)} of {len(seen)} ≤ {GOAL_S:g} s); "
            f"the first event {first:.1f} s",
        )
    rep.known_limit(
        f"the ARX learning in the run alone settles within 2 % in ≤ {GOAL_S:g} s the first time the payload steps into a regime "
        "(a regime it has not met cannot be remembered; a bank carried from a calibration run removes the first meeting)",
        f"the first event {first:.1f} s",
        first <= GOAL_S,
    )
    carried_bank_text(rep, arx, CALIBRATION_SHIFT_S, REGIME_BANK)
    settle_all = [e["settle_2pct_s"] for e in arx["regime_bank_carried"]["events"]]
    stays = [e["stays_2pct_s"] for e in arx["regime_bank_carried"]["events"]]
    if quick:
        rep.text(
            "(--quick: the calibration run is too short for its bank to store both regimes, so the carried bank is reported but "
            "not checked; the full run checks it.)"
        )
        return
    rep.check_every(
        f"with the regime bank carried from a calibration run: within 2 % in ≤ {GOAL_S:g} s after every payload step, the first included",
        [x <= GOAL_S for x in settle_all],
        "per event " + ", ".join(f"{x:.1f}" for x in settle_all) + " s (delay to stay within 2 %: " + ", ".join(f"{x:.1f}" for x in stays) + " s); "
        f"learned in the run alone, the first event {first:.1f} s",
    )


def _dither_checks(rep: Report, dither: dict[str, Any], quick: bool) -> None:
    """The D/A carries each dither; the dithered ARX's delay as a known limit and against what the build reached."""
    dither_sent_checks(rep, dither)
    if quick:  # one event: the goal is judged on the full run's four
        return
    medians = (
        (d["amplitude_v"], key, d["arx"][key]["median_settle_2pct_s"]) for d in dither["runs"] for key in ("as_run", "reset_at_the_event", "change_detection")
    )
    best = min(medians, key=lambda x: x[2])
    measured = f"best: {best[2]:.2f} s ({1e3 * best[0]:g} mV, {best[1].replace('_', ' ')})"
    rep.known_limit(
        f"the ARX settles within 2 % in ≤ {GOAL_S:g} s after the payload steps (median over the events) with some dither amplitude", measured, best[2] <= GOAL_S
    )
    rep.check(
        f"the dithered ARX settles within 2 % in ≤ {DITHER_REACHED_S + DITHER_MARGIN_S:g} s after the payload steps (median over the events, "
        f"best amplitude; reached {DITHER_REACHED_S:g} s, margin {DITHER_MARGIN_S:g} s)",
        best[2] <= DITHER_REACHED_S + DITHER_MARGIN_S,
        measured,
    )


def _checks_and_thesis(rep: Report, rows_data: dict[str, dict[str, Any]], thesis_key: str, events: list[float], best_key: str | None, quick: bool) -> None:
    """The checks and the comparison with the thesis."""
    th = rows_data[thesis_key]
    th0 = th["events"][0]
    applied_ok = len(th["events_applied_s"]) == len(events) and all(abs(a - e) <= 0.06 for a, e in zip(th["events_applied_s"], events))
    rep.check("the payload events happened at their scheduled times (plant record)", applied_ok, ", ".join(f"{a:.3f}" for a in th["events_applied_s"]) + " s")
    rep.check(
        "releasing the payload steps the true first mode up by more than twice the tolerance",
        th0["step_pct"] > 2 * 100 * TOLERANCE,
        f"{th0['step_pct']:+.1f} %",
    )
    key_settings = [k for k in (thesis_key, best_key) if k is not None]
    key_events = [e for k in dict.fromkeys(key_settings) for e in rows_data[k]["events"] if e["started_on_the_old_side"]]
    rep.check(
        "delay to 50 %: finite and positive after every measurable event, for the thesis's and the best setting",
        bool(key_events) and all(0 < e["delay_50pct_s"] < math.inf for e in key_events),
        "; ".join(f"{k}: " + ", ".join(f"{e['delay_50pct_s']:.2f}" for e in rows_data[k]["events"]) + " s" for k in dict.fromkeys(key_settings)),
    )
    if best_key is not None:
        rep.check(
            "delay to 2 %: finite and positive for every event, for at least one setting",
            0 < rows_data[best_key]["max_settle_2pct_s"] < math.inf,
            f"{best_key}: {rows_data[best_key]['median_settle_2pct_s']:.2f} s (median), {rows_data[best_key]['max_settle_2pct_s']:.2f} s (longest)",
        )
    else:
        rep.check("delay to 2 %: finite and positive for every event, for at least one setting", False, "no setting settled within 2 % after every event")
    if not quick:
        faster = [
            k for k, d in rows_data.items() if d["identifier"] == "etfe" and d["fft_width"] < 2048 and d["median_settle_2pct_s"] < th["median_settle_2pct_s"]
        ]
        rep.check(
            "a shorter history tracks faster: some N < 2048 settles sooner (median) than the thesis's setting",
            bool(faster),
            ", ".join(f"{k} {d['median_settle_2pct_s']:.1f} s" for k, d in rows_data.items()),
        )
        rep.thesis(
            "The identified modes lagged the true changes by 1 to 4 s (changes slower than about 5 %/s were tracked).",
            f"After steps of {th0['step_pct']:+.1f} % at the thesis's settings (window {th['window_s']:.2f} s): {th['median_delay_50pct_s']:.1f} s to half-way, "
            f"{th['median_settle_2pct_s']:.1f} s to stay within 2 % (median of {len(events)} events; {th['settled_events']} settled).",
            True if th["median_delay_50pct_s"] <= 4.0 else ("partly" if th["median_delay_50pct_s"] <= 8.0 else False),
        )
        if best_key is not None:
            b = rows_data[best_key]
            big_alpha = [d for d in rows_data.values() if d["identifier"] == "etfe" and d["fft_width"] == 2048 and d["alpha"] > THESIS_SETTING[1]]
            rep.thesis(
                "Future work (§5.3): measure the identifier's delay precisely with a discontinuous change; find settings that track faster.",
                f"Best setting found: {_label(b)}: {b['median_settle_2pct_s']:.1f} s to 2 % (thesis's {th['median_settle_2pct_s']:.1f} s), "
                f"{b['median_delay_50pct_s']:.1f} s to 50 % (thesis's {th['median_delay_50pct_s']:.1f} s), error at the end {100 * b['median_rel_error_end']:.1f} % "
                f"(thesis's {100 * th['median_rel_error_end']:.1f} %), median confidence {b['median_confidence']:.2f} ({th['median_confidence']:.2f}). "
                + (
                    "A larger α alone does not help at N = 2048: "
                    + ", ".join(
                        f"α = {d['alpha']:g} settles {d['settled_events']}/{len(events)} events, confidence {d['median_confidence']:.2f}" for d in big_alpha
                    )
                    + " (the average then holds about one window's data, and a single snapshot's 2×2 solve is undefined)."
                    if big_alpha
                    else ""
                ),
                None,
            )
    else:
        d = rows_data[thesis_key]
        rep.thesis(
            "The identified modes lagged the true changes by 1 to 4 s.",
            f"Quick run, N = {d['fft_width']}, α = {d['alpha']:g}: {d['median_settle_2pct_s']:.1f} s to 2 %, {d['median_delay_50pct_s']:.1f} s to 50 %.",
            None,
        )
