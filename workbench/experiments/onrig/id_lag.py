"""``id-lag``: the identifier's delay after discontinuous changes, the payload released and picked up mid-run (thesis §5.3).

The thesis's future work asks for discontinuous parameter changes (picking up
or releasing the payload) to measure the identifier's delay precisely.  On
the inspection loop the true first mode itself moves by 20 % or more, so a
step in it would be hard to separate from the trajectory; this experiment
drives the arm instead along a small loop of irregular square teeth (6 teeth
of 2–5 in, 37 in along the loop's bottom edge from its bottom-right corner,
closed, 5 in/s, 24 s per lap; written to ``records/idlag_trajectory.json``)
where the true first mode stays within about 1.5 % with the payload and
0.6 % without it.  The 15.65 lb payload starts attached and is released and
picked up again at ``EVENTS_S`` (``RALF_SCENARIO``): the first mode steps by
about +9.5 % (4.17 → 4.56 Hz) and back.  PI control only, OATF off; the same
sensor-noise seed for every run.

Measured per identifier setting (N, α; l = 20; smoothing scaled with N, 17
bins at N = 2048) from the identified first pole in the controller's record
(held between interrupts, whatever its confidence) against the plant's
ground truth, for every event:

* ``m(t)``: the centred running median of the identified pole over ±1 s (a
  single estimate scatters by a few per cent and jumps to other peaks for a
  while; a centred median adds no delay to a step);
* **delay to 2 %**: the first time after the event from which ``m(t)`` stays
  within 2 % of the new true first-mode frequency for ``HOLD_S`` (∞ if not
  before the next event or the end);
* **delay to 50 %**: the first time ``m(t)`` crosses half-way from the old to
  the new true frequency (NaN when ``m`` was not on the old side at the event);
* the first raw estimate inside the 2 % band, the error before each event,
  the error over the last 8 s, the median confidence.

The thesis's settings (N = 2048, α = 0.1, l = 20) against others: shorter
histories (N = 1024, 512) with averaging weights small enough to keep
several independent windows in the average (α = 0.05, 0.02), and a large
α at N = 2048 (a larger α alone leaves about one window's worth of data in
the average, and the 2×2 solve of a single snapshot is undefined).  The
best setting is the one with the shortest median delay to 2 % among those
that settle after every event.  ``--quick``: N = 1024, α = 0.05 only, one
release at 10 s, 26 s.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from controller.excitation import DitherConfig
from controller.trajectory import SampledTrajectory, WaypointTrajectory, sample_trajectory
from dsp_service.arx import RecursiveArx, RegimeBankState
from dsp_service.identifier import IdentifierConfig, arx_config
from plant_emulator.model.modes import modal_parameters
from workbench.campaign.rigs import run_rigs
from workbench.experiments.analysis import THESIS_BATCH_SIZE, centred_median, costs_over
from workbench.experiments.framework import ExperimentContext, experiment, run_layout
from workbench.experiments.report import Report, new_figure
from workbench.hil import RunRecord
from workbench.rig_spec import RigSpec

if TYPE_CHECKING:
    from matplotlib.figure import Figure

FS_HZ = 200.0
SPEED = 5.0
EVENTS_S = (22.0, 42.0, 62.0, 82.0)
"""Payload released, picked up, released, picked up (the payload starts attached)."""
DURATION_S = 102.0
QUICK_EVENTS_S = (10.0,)
QUICK_DURATION_S = 26.0
TOLERANCE = 0.02
HOLD_S = 2.0
MEDIAN_HALF_S = 1.0
SETTINGS: tuple[tuple[int, float, str], ...] = (
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
QUICK_SETTINGS: tuple[tuple[int, float, str], ...] = ((1024, 0.05, "etfe"), (2048, 0.1, "arx"))
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
ORACLE_GAMMA = 1e-3
"""The weight the replayed ARX's reset at the true event time leaves on the data before it (``RecursiveArx.discount``)."""
_ARX = IdentifierConfig()
_BANKED = IdentifierConfig(method="arx", sample_rate_hz=FS_HZ, arx_regime_bank=REGIME_BANK)
"""The DSP's ARX with a regime bank (docs/identification.md §5c-5d), as the replays build it."""
_DITHER = DitherConfig()
"""The dither's default band and period (the runs set only its amplitude)."""
ARX_FORGETTING = _ARX.arx_forgetting
"""The ARX identifier's forgetting factor per model sample (its default; memory 1/(1 − λ) model samples)."""
ARX_MEMORY_S = _ARX.arx_decimation / (_ARX.sample_rate_hz * (1.0 - ARX_FORGETTING))
"""The ARX model's memory in seconds (1/(1 − λ) samples at fs / D)."""

# the small loop: a corner of the inspection loop and its bottom edge's direction
_START = (-19.437, 196.612)
_ALONG = (-0.985, -0.174)
_TEETH = ((3.0, 4.0), (4.5, 2.5), (2.0, 5.0), (3.5, 3.0), (5.0, 4.5), (2.5, 2.0))
"""(width, height) in inches of each tooth; each tooth is followed by a gap of 0.8 × its width."""


def smoothing_window(n: int) -> int:
    """The thesis's 17 bins at N = 2048, scaled with N (the same width in Hz), odd, at least 5."""
    w = int(round(17 * n / 2048))
    w += 1 - w % 2
    return max(5, w)


def idlag_trajectory() -> WaypointTrajectory:
    """The small closed loop of irregular teeth (see the module doc)."""
    p0 = np.array(_START)
    u = np.array(_ALONG) / np.hypot(*_ALONG)
    nrm = np.array([-u[1], u[0]])
    if nrm[1] < 0:
        nrm = -nrm
    pts = [(0.0, 0.0)]
    s = 0.0
    for w, h in _TEETH:
        s += w
        pts += [(s, 0.0), (s, h)]
        s += 0.8 * w
        pts += [(s, h), (s, 0.0)]
    wps = []
    for i, (a, b) in enumerate(pts):
        p = p0 + a * u + b * nrm
        wps.append({"x_in": round(float(p[0]), 3), "y_in": round(float(p[1]), 3), "pause_s": 1.0 if i == 0 else 0.0})
    return WaypointTrajectory(
        name="idlag_teeth",
        description="Irregular square teeth near the inspection loop's bottom-right corner: a nearly constant configuration with rich excitation (ralf-hil experiment id-lag)",
        speed_in_per_s=SPEED,
        closed=True,
        waypoints=wps,
    )


def event_delays(
    t: np.ndarray, f: np.ndarray, true1: np.ndarray, tm: np.ndarray, m: np.ndarray, at_s: float, until_s: float, tolerance: float = TOLERANCE
) -> dict[str, Any]:
    """Delays after one payload event at ``at_s`` (the next event or the run's end at ``until_s``), see the module doc."""
    before = (t >= at_s - 8.0) & (t < at_s)
    old = float(np.median(true1[before]))
    new = float(np.median(true1[(t >= at_s + 1.0) & (t < until_s)]))
    half = 0.5 * (old + new)
    sign = 1.0 if new > old else -1.0
    win = (tm >= at_s) & (tm < until_s)
    tw, mw = tm[win], m[win]
    truth_w = np.interp(tw, t, true1)
    inside = np.abs(mw - truth_w) / truth_w <= tolerance
    dt = float(tm[1] - tm[0])
    hold = int(round(HOLD_S / dt))
    settle = math.inf
    for k in range(max(0, inside.size - hold)):
        if inside[k : k + hold + 1].all():
            settle = float(tw[k] - at_s)
            break
    # stays within the tolerance up to the next event: the median's last second before it already sees it
    upto = tw < until_s - MEDIAN_HALF_S
    outside = np.flatnonzero(~inside[upto])
    if not upto.any() or (outside.size and outside[-1] == upto.sum() - 1):
        stays = math.inf
    else:
        stays = float(tw[outside[-1] + 1] - at_s) if outside.size else float(tw[0] - at_s)
    m_at = np.interp(at_s - 0.5, tm, m)  # the running median just before the event
    valid_start = bool(np.isfinite(m_at)) and (m_at - half) * sign < 0
    cross = np.flatnonzero((mw - half) * sign >= 0)
    half_delay = float(tw[cross[0]] - at_s) if (valid_start and cross.size) else (math.inf if valid_start else float("nan"))
    raw_in = np.flatnonzero((t >= at_s) & (t < until_s) & (np.abs(f - true1) / true1 <= tolerance))
    pre_f = f[before & np.isfinite(f)]
    return {
        "at_s": at_s,
        "kind": "release" if new > old else "attach",
        "true_before_hz": old,
        "true_after_hz": new,
        "step_pct": 100.0 * (new - old) / old,
        "settle_2pct_s": settle,
        "stays_2pct_s": stays,
        "delay_50pct_s": half_delay,
        "started_on_the_old_side": valid_start,
        "first_raw_in_band_s": float(t[raw_in[0]] - at_s) if raw_in.size else math.inf,
        "median_rel_error_before": float(np.median(np.abs(pre_f - old) / old)) if pre_f.size else float("nan"),
    }


def series_delays(t: np.ndarray, f: np.ndarray, true1: np.ndarray, events_s: Sequence[float], tolerance: float = TOLERANCE) -> dict[str, Any]:
    """Every event's delays for one identified series ``f`` at times ``t`` against the truth ``true1``, and their
    summary (median over events; ∞ counts as the largest)."""
    tm, m = centred_median(t, f, MEDIAN_HALF_S)
    ends = list(events_s[1:]) + [float(t[-1])]
    events = [event_delays(t, f, true1, tm, m, a, b, tolerance) for a, b in zip(events_s, ends)]
    settle = np.array([e["settle_2pct_s"] for e in events])
    stays = np.array([e["stays_2pct_s"] for e in events])
    half = np.array([e["delay_50pct_s"] for e in events])
    half_ok = half[np.isfinite(half)]
    end = (t >= t[-1] - 8.0) & np.isfinite(f)
    rel_end = np.abs(f[end] - true1[end]) / true1[end]
    first_estimate = float(t[np.flatnonzero(np.isfinite(f))[0]]) if np.isfinite(f).any() else float("nan")
    return {
        "events": events,
        "settled_events": int(np.isfinite(settle).sum()),
        "median_settle_2pct_s": float(np.median(settle)) if settle.size else float("nan"),
        "max_settle_2pct_s": float(np.max(settle)) if settle.size else float("nan"),
        "stayed_events": int(np.isfinite(stays).sum()),
        "median_stays_2pct_s": float(np.median(stays)) if stays.size else float("nan"),
        "median_delay_50pct_s": float(np.median(half_ok)) if half_ok.size else float("nan"),
        "measurable_50pct_events": int(half_ok.size),
        "median_rel_error_end": float(np.median(rel_end)) if rel_end.size else float("nan"),
        "first_estimate_s": first_estimate,
        "median_series": {"t_s": tm.tolist(), "f_hz": m.tolist()},
    }


def applied_events(res: RunRecord) -> list[float]:
    """The times the plant's record shows the payload switching (controller time)."""
    truth_t = np.asarray(res.truth_columns["sim_time_s"]) - res.sample_period_s
    attached = np.asarray(res.truth_columns["payload_attached"]).astype(bool)
    switch = np.flatnonzero(attached[:-1] != attached[1:])
    return [float(truth_t[i + 1]) for i in switch]


def step_delays(res: RunRecord, events_s: list[float], tolerance: float = TOLERANCE) -> dict[str, Any]:
    """Every event's delays for one run (:func:`series_delays` of the record's identified first pole)."""
    t = res.t_s
    f = np.asarray(res.columns["f_id_hz"], dtype=float)
    conf = np.asarray(res.columns["id_confidence"], dtype=float)
    out = series_delays(t, f, res.true_mode_hz(t, 0), events_s, tolerance)
    out["events_applied_s"] = applied_events(res)
    out["median_confidence"] = float(np.median(conf[t >= events_s[0]]))
    return out


def payload_scenario(events: Sequence[float]) -> str:
    """The plant's ``RALF_SCENARIO``: the payload (attached at the start) released at the first event, picked up
    at the second, and so on."""
    return json.dumps([{"kind": "payload", "at_sim_time_s": at, "payload_attached": bool(i % 2)} for i, at in enumerate(events)])


def replay_arx(
    res: RunRecord,
    batch_size: int,
    discount_at_s: Sequence[float] = (),
    gamma: float = ORACLE_GAMMA,
    cfg: IdentifierConfig | None = None,
    bank: RegimeBankState | None = None,
) -> tuple[np.ndarray, list[float]]:
    """The DSP's recursive ARX replayed from the controller's record: the first pole after each batch, and the
    end times of the batches at which its change detector fired (``cfg.arx_change_detection``) or its regime bank
    switched to a remembered model (``cfg.arx_regime_bank``).

    The record holds the DSP's inputs and outputs sample for sample (the D/A
    commands ``u1_v``, ``u2_v`` and the deflections ``defl1_in``, ``defl2_in``);
    batch ``k`` is samples ``[k l, (k + 1) l)``, the model is the one
    ``method='arx'`` builds (:func:`dsp_service.identifier.arx_config`), restarted
    before the first batch as the controller's reset at the start does.
    ``discount_at_s``: before the batch that holds each of these times, the
    model's information is discounted by ``gamma`` (:meth:`RecursiveArx.discount`):
    a change detector that knows the change time. ``bank``: the regime bank
    another run learned (:func:`learn_bank`), loaded before the first batch as
    the DSP loads ``arx_regime_bank_file``."""
    first_pole, alarms, _model = _replayed_arx(res, batch_size, cfg, bank, discount_at_s, gamma)
    return first_pole, alarms


def learn_bank(res: RunRecord, batch_size: int) -> RegimeBankState:
    """The regime bank the DSP's ARX (``_BANKED``) holds at the end of ``res`` (replayed from its record):
    what ``arx_regime_bank_file`` would carry out of that run."""
    return _replayed_arx(res, batch_size, _BANKED, None)[2].bank_state()


def _replayed_arx(
    res: RunRecord,
    batch_size: int,
    cfg: IdentifierConfig | None,
    bank: RegimeBankState | None,
    discount_at_s: Sequence[float] = (),
    gamma: float = ORACLE_GAMMA,
) -> tuple[np.ndarray, list[float], RecursiveArx]:
    rec = res.controller_record()
    u = np.vstack([np.asarray(rec["u1_v"], dtype=float), np.asarray(rec["u2_v"], dtype=float)])
    y = np.vstack([np.asarray(rec["defl1_in"], dtype=float), np.asarray(rec["defl2_in"], dtype=float)])
    arx = RecursiveArx(arx_config(cfg if cfg is not None else IdentifierConfig(method="arx", sample_rate_hz=1.0 / res.sample_period_s)))
    arx.restart()
    if bank is not None:
        arx.load_bank(bank)
    pending = sorted(discount_at_s)
    dt = res.sample_period_s
    f = np.full(u.shape[1] // batch_size, np.nan)
    alarms: list[float] = []
    for k in range(f.size):
        while pending and pending[0] < (k + 1) * batch_size * dt:
            pending.pop(0)
            arx.discount(gamma)
        before = arx.changes_detected + arx.bank_switches
        arx.update(u[:, k * batch_size : (k + 1) * batch_size], y[:, k * batch_size : (k + 1) * batch_size])
        if arx.changes_detected + arx.bank_switches > before:
            alarms.append((k + 1) * batch_size * dt)
        poles = arx.poles()
        f[k] = poles[0].frequency_hz if poles else np.nan
    return f, alarms, arx


def held(per_batch: np.ndarray, n_ticks: int, batch_size: int) -> np.ndarray:
    """Per controller tick, the estimate of the batch whose interrupt it holds: batch ``k``'s from tick ``(k + 2) l``
    (the batch is complete at ``(k + 1) l``; its interrupt is applied one batch later)."""
    k = np.arange(n_ticks) // batch_size - 2
    return np.where(k >= 0, per_batch[np.clip(k, 0, per_batch.size - 1)], np.nan)


def replay_matches_record(res: RunRecord, per_batch: np.ndarray, batch_size: int) -> float:
    """Largest difference between the replayed first pole and the record's ``f_id_hz`` at the middle of each
    holding interval (∞ if their missing estimates differ)."""
    rec = np.asarray(res.columns["f_id_hz"], dtype=float)
    ticks = (np.arange(per_batch.size) + 2) * batch_size + batch_size // 2
    keep = ticks < rec.size
    a, b = per_batch[keep], rec[ticks[keep]]
    if not np.array_equal(np.isnan(a), np.isnan(b)):
        return math.inf
    ok = ~np.isnan(a)
    return float(np.max(np.abs(a[ok] - b[ok]))) if ok.any() else math.inf


def _dither_name(amplitude_v: float) -> str:
    return f"arx_dither_{1e3 * amplitude_v:g}mv".replace(".", "p")


STEADY_AFTER_S = 8.0
"""The steady stretch of an event's interval starts this long after it (the estimator's floor, :func:`steady_share`)."""


def steady_share(t: np.ndarray, f: np.ndarray, true1: np.ndarray, events: Sequence[float], tolerance: float = TOLERANCE) -> float:
    """The share of the time from ``STEADY_AFTER_S`` after each event to the next (or the end, less the median's
    half window) in which the centred running median of ``f`` is within ``tolerance`` of the truth: the
    estimator's floor against the criterion, with no change to follow. Below 1, no reset can make the
    2-s hold certain."""
    tm, m = centred_median(t, f, MEDIAN_HALF_S)
    truth = np.interp(tm, t, true1)
    ends = [*events[1:], float(t[-1])]
    sel = np.zeros(tm.size, dtype=bool)
    for a, b in zip(events, ends):
        sel |= (tm >= a + STEADY_AFTER_S) & (tm < b - MEDIAN_HALF_S)
    ok = sel & np.isfinite(m)
    return float(np.mean(np.abs(m[ok] - truth[ok]) / truth[ok] <= tolerance)) if ok.any() else float("nan")


def arx_replays(res: RunRecord, events: Sequence[float], calibration: RunRecord | None = None) -> dict[str, Any]:
    """The DSP's ARX replayed from one run's record (:func:`replay_arx`): as run, reset at the true events
    (γ ``ORACLE_GAMMA``), with its change detector, with a regime bank learned in the run, and (``calibration``:
    an earlier run of the same rig, another noise seed) with the bank that run learned carried in from its
    start, as ``arx_regime_bank_file`` carries it; the delays of each (:func:`series_delays`)."""
    t_r, true_r = res.t_s, res.true_mode_hz(res.t_s, 0)
    replayed, _ = replay_arx(res, THESIS_BATCH_SIZE)
    reset, _ = replay_arx(res, THESIS_BATCH_SIZE, discount_at_s=applied_events(res))
    detected, alarms = replay_arx(res, THESIS_BATCH_SIZE, cfg=IdentifierConfig(method="arx", sample_rate_hz=FS_HZ, arx_change_detection=True))
    banked, switches = replay_arx(res, THESIS_BATCH_SIZE, cfg=_BANKED)
    out: dict[str, Any] = {
        "max_difference_to_the_record_hz": replay_matches_record(res, replayed, THESIS_BATCH_SIZE),
        "gamma": ORACLE_GAMMA,
        "as_run": series_delays(t_r, held(replayed, t_r.size, THESIS_BATCH_SIZE), true_r, events),
        "reset_at_the_event": series_delays(t_r, held(reset, t_r.size, THESIS_BATCH_SIZE), true_r, events),
        "change_detection": series_delays(t_r, held(detected, t_r.size, THESIS_BATCH_SIZE), true_r, events),
        "change_alarms_s": alarms,
        "regime_bank": series_delays(t_r, held(banked, t_r.size, THESIS_BATCH_SIZE), true_r, events),
        "regime_switches_s": switches,
    }
    keys = ["as_run", "reset_at_the_event", "change_detection", "regime_bank"]
    if calibration is not None:
        carried_bank = learn_bank(calibration, THESIS_BATCH_SIZE)
        carried, carried_switches = replay_arx(res, THESIS_BATCH_SIZE, cfg=_BANKED, bank=carried_bank)
        out["regime_bank_carried"] = series_delays(t_r, held(carried, t_r.size, THESIS_BATCH_SIZE), true_r, events)
        out["carried_switches_s"] = carried_switches
        out["carried_bank"] = {
            "regimes": carried_bank.regimes,
            "signatures_hz": carried_bank.signature.tolist(),
            "seed": calibration.settings["plant"].get("seed"),
            "events_s": [float(e["at_sim_time_s"]) for e in json.loads(str(calibration.settings["plant"].get("scenario", "[]")))],
        }
        keys.append("regime_bank_carried")
    for key in keys:
        out[key].pop("median_series")  # the delays are the results; the series would triple the file
    out["steady_within_2pct"] = steady_share(t_r, held(replayed, t_r.size, THESIS_BATCH_SIZE), true_r, events)
    return out


def dither_study(base: RunRecord, base_arx: dict[str, Any], runs: Sequence[RunRecord], amplitudes: Sequence[float], events: Sequence[float]) -> dict[str, Any]:
    """Cost and benefit of the valve commands' dither: per amplitude, the §4.2.1 costs over the whole run
    (RMS deflection velocity and acceleration per link, :func:`costs_over`) against the undithered ARX run
    ``base`` (the same seed and trajectory; with the OATF off the identifier does not act on the plant, so
    the dither is the only difference), the dither as the D/A sent it (RMS of ``u − pi``, the PI's output
    before the dither), and the ARX's delays as run, reset at the true event and with its detector."""
    mask = np.ones(base.t_s.size, dtype=bool)
    base_cost = costs_over(base.deflections, mask, base.sample_period_s)
    rows = []
    for amp, r in zip(amplitudes, runs):
        cost = costs_over(r.deflections, np.ones(r.t_s.size, dtype=bool), r.sample_period_s)
        rec = r.controller_record()
        sent = np.vstack(
            [
                np.asarray(rec["u1_v"], dtype=float) - np.asarray(rec["pi1_v"], dtype=float),
                np.asarray(rec["u2_v"], dtype=float) - np.asarray(rec["pi2_v"], dtype=float),
            ]
        )
        rows.append(
            {
                "amplitude_v": amp,
                "sent_rms_v": np.sqrt(np.mean(sent**2, axis=1)).tolist(),
                "velocity_rms": cost["velocity_rms"],
                "acceleration_rms": cost["acceleration_rms"],
                "velocity_ratio": [a / b for a, b in zip(cost["velocity_rms"], base_cost["velocity_rms"])],
                "acceleration_ratio": [a / b for a, b in zip(cost["acceleration_rms"], base_cost["acceleration_rms"])],
                "arx": arx_replays(r, events),
            }
        )
    return {"base": {"velocity_rms": base_cost["velocity_rms"], "acceleration_rms": base_cost["acceleration_rms"], "arx": base_arx}, "runs": rows}


def _report_dither(rep: Report, dither: dict[str, Any], events: Sequence[float], quick: bool) -> None:
    """The dither section of the report: cost against benefit per amplitude, and the goal's check."""
    if not dither["runs"]:
        return
    rep.heading("Persistent excitation: a dither on the valve commands")
    rep.text(
        "The payload kick rings the second mode, and on the return stroke nothing excites the first for seconds, so the data after a "
        "change may hold no information about the new first mode. The controller's opt-in dither (`RALF_DITHER=amplitude_v=...`, "
        f"`controller/excitation.py`: a periodic multisine, flat over every bin of its {_DITHER.period_ticks / FS_HZ:g}-s period in "
        f"{_DITHER.band_hz[0]:g}–{_DITHER.band_hz[1]:g} Hz, independent random phases per "
        "valve) is added to both valve commands after the PI, before the D/A, so the DSP's inputs carry it. Same seed, trajectory and "
        "events as the ARX run above; with the OATF off the identifier does not act on the plant, so the dither is the only difference. "
        "**Cost**: RMS deflection velocity and acceleration over the whole run (the §4.2.1 metrics), against the undithered run. "
        "**Benefit**: the ARX's median delay to stay within 2 % for 2 s, as run, with a reset at the true event and with its change detector "
        "(replayed from each record)."
    )

    _dither_table(rep, dither)
    _dither_checks(rep, dither, quick)


def _dither_table(rep: Report, dither: dict[str, Any]) -> None:
    """The dither's cost and the ARX's delays per amplitude."""

    def arx_cells(a: dict[str, Any]) -> list[Any]:
        """The ARX's delays and accuracy of one run: per event, the three medians, steady share, error at the end."""
        return [
            ", ".join(f"{e['settle_2pct_s']:.1f}" for e in a["as_run"]["events"]),
            a["as_run"]["median_settle_2pct_s"],
            a["reset_at_the_event"]["median_settle_2pct_s"],
            a["change_detection"]["median_settle_2pct_s"],
            100 * a["steady_within_2pct"],
            100 * a["as_run"]["median_rel_error_end"],
        ]

    base = dither["base"]
    rows = [["none", "–", *base["velocity_rms"], "1 / 1", "1 / 1", *arx_cells(base["arx"])]]
    for d in dither["runs"]:
        rows.append(
            [
                f"{1e3 * d['amplitude_v']:g} mV",
                " / ".join(f"{1e3 * x:.1f}" for x in d["sent_rms_v"]),
                *d["velocity_rms"],
                " / ".join(f"{x:.2f}" for x in d["velocity_ratio"]),
                " / ".join(f"{x:.2f}" for x in d["acceleration_ratio"]),
                *arx_cells(d["arx"]),
            ]
        )
    rep.table(
        [
            "dither (RMS per valve)",
            "sent: RMS of u − PI output (mV, valve 1 / 2)",
            "RMS defl. velocity link 1 (in/s)",
            "link 2 (in/s)",
            "velocity / undithered (link 1 / 2)",
            "acceleration / undithered",
            "ARX delay to 2 %, per event (s)",
            "median, as run (s)",
            "median, reset at the event (s)",
            "median, change detector (s)",
            f"steady: time within 2 % from {STEADY_AFTER_S:g} s after each event (%)",
            "error at the end (%)",
        ],
        rows,
        caption="The dither's cost and the ARX's delays per amplitude (undithered: the ARX run above)",
        digits=3,
    )


def _dither_checks(rep: Report, dither: dict[str, Any], quick: bool) -> None:
    """The D/A carries each dither; the dithered ARX's delay as a known limit and against what the build reached."""
    for d in dither["runs"]:
        # the hook works: what the D/A sent above the PI's output is the dither (plus the D/A's rounding, LSB/√12 = 1.4 mV)
        expect = math.hypot(d["amplitude_v"], 20.0 / 4096 / math.sqrt(12.0))
        ok = all(abs(x / expect - 1.0) <= 0.2 for x in d["sent_rms_v"])
        rep.check(
            f"dither {1e3 * d['amplitude_v']:g} mV: the D/A carries it (RMS of u − PI output within 20 % of √(A² + LSB²/12))",
            ok,
            " / ".join(f"{1e3 * x:.2f}" for x in d["sent_rms_v"]) + f" mV for {1e3 * expect:.2f} mV",
        )
    best = min(
        (
            (d["amplitude_v"], key, d["arx"][key]["median_settle_2pct_s"])
            for d in dither["runs"]
            for key in ("as_run", "reset_at_the_event", "change_detection")
        ),
        key=lambda x: x[2],
    )
    if quick:  # one event: the goal is judged on the full run's four
        return
    measured = f"best: {best[2]:.2f} s ({1e3 * best[0]:g} mV, {best[1].replace('_', ' ')})"
    rep.known_limit(
        f"the ARX settles within 2 % in ≤ {GOAL_S:g} s after the payload steps (median over the events) with some dither amplitude",
        measured,
        best[2] <= GOAL_S,
    )
    rep.check(
        f"the dithered ARX settles within 2 % in ≤ {DITHER_REACHED_S + DITHER_MARGIN_S:g} s after the payload steps (median over the events, "
        f"best amplitude; reached {DITHER_REACHED_S:g} s, margin {DITHER_MARGIN_S:g} s)",
        best[2] <= DITHER_REACHED_S + DITHER_MARGIN_S,
        measured,
    )


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
    traj = idlag_trajectory()
    traj_path = ctx.path("records/idlag_trajectory.json")
    traj_path.write_text(json.dumps(traj.model_dump(), indent=1) + "\n", encoding="utf-8")
    sampled = sample_trajectory(traj, 1.0 / FS_HZ)
    theta = sampled.joints.theta
    f_free = modal_parameters(theta[:, 0], theta[:, 1], False)[0][:, 0]
    f_load = modal_parameters(theta[:, 0], theta[:, 1], True)[0][:, 0]
    seed = int(ctx.rng("plant-seed").integers(0, 2**31 - 1))
    scenario = payload_scenario(events)
    specs = _setting_specs(duration, traj_path, scenario, seed, settings)
    amplitudes, dither_specs, calibration_spec = _dither_and_calibration_specs(quick, specs, settings, events, seed)
    all_runs = run_rigs(ctx, [*specs, *dither_specs, calibration_spec], in_process=quick, description="id-lag runs")
    runs, dither_runs, calibration_run = all_runs[: len(specs)], all_runs[len(specs) : -1], all_runs[-1]
    rows_data = _settings_rows(settings, runs, events)
    arx_replay, dither = _arx_studies(settings, runs, events, calibration_run, dither_runs, amplitudes)
    thesis_key, best_key = _results(rep, settings, rows_data, events, traj_path, sampled, f_load, f_free, duration, arx_replay, dither)
    th0 = _runs_section(ctx, rep, rows_data, thesis_key, runs, quick, traj_path, sampled, f_load, f_free, duration, events, best_key)
    _events_section(rep, rows_data, runs, settings, events)
    if arx_replay:
        _report_arx(rep, arx_replay, events, quick)
    _report_dither(rep, dither, events, quick)
    fig = _delay_figure(rows_data, len(events))
    rep.figure(
        fig, "id_lag_delays.png", "Median delay to 2 % and to 50 % over the events, and the error at the end, per setting (∞: some event never settled)."
    )
    _checks_and_thesis(rep, rows_data, thesis_key, events, th0, best_key, quick)
    rep.attach(traj_path, "the trajectory (way-points) of the runs")
    for r in runs:
        rep.attach(r.output(".npz"), f"run record: {r.label}")
    return rep


def _setting_specs(duration: float, traj_path: Path, scenario: str, seed: int, settings: tuple[tuple[int, float, str], ...]) -> list[RigSpec]:
    """One run per identifier setting, PI only along the loop of teeth with the payload events."""
    specs = [
        RigSpec(
            _name(n, a, m),
            controller={
                "duration_s": duration,
                "tip_speed_in_s": SPEED,
                "trajectory": str(traj_path),
                "batch_size": THESIS_BATCH_SIZE,
                "tf_download_samples": 0,
                "oatf_mode": "off",
            },
            plant={"payload_attached": True, "scenario": scenario, "seed": seed},
            dsp={"batch_size": THESIS_BATCH_SIZE, "fft_width": n, "alpha": a, "smoothing": {"window": smoothing_window(n)}, "identifier": m},
            label=f"N = {n}, α = {a:g}, l = {THESIS_BATCH_SIZE}, smoothing {smoothing_window(n)} bins" + ("" if m == "etfe" else f", {m}")
            if m != "arx"
            else f"recursive ARX (fs/{_ARX.arx_decimation}, na {_ARX.arx_na}, nb {_ARX.arx_nb}, Steiglitz–McBride, Huber k {_ARX.arx_huber_k:g}), "
            f"λ = {ARX_FORGETTING:g} per model sample (memory {ARX_MEMORY_S:.2g} s), l = {THESIS_BATCH_SIZE}",
        )
        for n, a, m in settings
    ]
    return specs


def _dither_and_calibration_specs(
    quick: bool, specs: list[RigSpec], settings: tuple[tuple[int, float, str], ...], events: list[float], seed: int
) -> tuple[tuple[float, ...], list[RigSpec], RigSpec]:
    """The ARX run with each dither amplitude, and the calibration run whose regime bank is carried in."""
    amplitudes = QUICK_DITHER_AMPLITUDES_V if quick else DITHER_AMPLITUDES_V
    arx_spec = next(sp for sp, (_n, _a, m) in zip(specs, settings) if m == "arx")
    dither_specs = [
        RigSpec(
            _dither_name(amp),
            controller={**arx_spec.controller, "dither": {"amplitude_v": amp}},
            plant=dict(arx_spec.plant),
            dsp=dict(arx_spec.dsp),
            label=f"{arx_spec.label}; valve dither {1e3 * amp:g} mV RMS",
        )
        for amp in amplitudes
    ]
    calibration_events = [at + CALIBRATION_SHIFT_S for at in events]
    calibration_spec = RigSpec(
        "arx_calibration",
        controller=dict(arx_spec.controller),
        plant={
            **arx_spec.plant,
            "seed": seed + 1,
            "scenario": payload_scenario(calibration_events),
        },
        dsp=dict(arx_spec.dsp),
        label=f"{arx_spec.label}; calibration run (sensor-noise seed {seed + 1}, payload events at "
        + ", ".join(f"{at:g}" for at in calibration_events)
        + " s)",
    )
    return amplitudes, dither_specs, calibration_spec


def _settings_rows(settings: tuple[tuple[int, float, str], ...], runs: list[RunRecord], events: list[float]) -> dict[str, dict[str, Any]]:
    """The delays of every setting's run, with its settings."""
    rows_data: dict[str, dict[str, Any]] = {}
    for (n, a, m), r in zip(settings, runs):
        d = step_delays(r, events)
        d.update(
            {
                "identifier": m,
                "fft_width": n,
                "alpha": a,
                "batch_size": THESIS_BATCH_SIZE,
                "smoothing_window": smoothing_window(n),
                "window_s": n / FS_HZ,
                "averaging_span_s": (n + THESIS_BATCH_SIZE * (1 / a - 1)) / FS_HZ,
                "run": r.run_facts(),
            }
        )
        rows_data[_name(n, a, m)] = d
    return rows_data


def _arx_studies(
    settings: tuple[tuple[int, float, str], ...],
    runs: list[RunRecord],
    events: list[float],
    calibration_run: RunRecord,
    dither_runs: list[RunRecord],
    amplitudes: tuple[float, ...],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ARX replayed from its record, and the dither study."""
    arx_replay: dict[str, Any] = {}
    for (_n, _a, m), r in zip(settings, runs):
        if m == "arx":
            arx_replay = arx_replays(r, events, calibration_run)
    arx_run = next(r for (_n, _a, m), r in zip(settings, runs) if m == "arx")
    dither = dither_study(arx_run, arx_replay, dither_runs, amplitudes, events)
    return arx_replay, dither


def _results(
    rep: Report,
    settings: tuple[tuple[int, float, str], ...],
    rows_data: dict[str, dict[str, Any]],
    events: list[float],
    traj_path: Path,
    sampled: SampledTrajectory,
    f_load: np.ndarray,
    f_free: np.ndarray,
    duration: float,
    arx_replay: dict[str, Any],
    dither: dict[str, Any],
) -> tuple[str, str | None]:
    """Everything numeric the report keeps; the thesis's and the best setting."""
    thesis_key = _name(*THESIS_SETTING) if THESIS_SETTING in settings else _name(*settings[0])
    complete = {k: v for k, v in rows_data.items() if v["settled_events"] == len(events)}
    best_key = min(complete, key=lambda k: (complete[k]["median_settle_2pct_s"], complete[k]["median_rel_error_end"])) if complete else None
    rep.results = {
        "trajectory": {
            "file": traj_path.name,
            "lap_s": len(sampled.joints.phi) / FS_HZ,
            "true_f1_payload_hz": [float(f_load.min()), float(f_load.max())],
            "true_f1_free_hz": [float(f_free.min()), float(f_free.max())],
        },
        "events_s": events,
        "duration_s": duration,
        "tolerance": TOLERANCE,
        "hold_s": HOLD_S,
        "median_half_window_s": MEDIAN_HALF_S,
        "settings": rows_data,
        "thesis_setting": thesis_key,
        "best_setting": best_key,
        "arx_replay": arx_replay,
        "dither": dither,
    }
    return thesis_key, best_key


def _runs_section(
    ctx: ExperimentContext,
    rep: Report,
    rows_data: dict[str, dict[str, Any]],
    thesis_key: str,
    runs: list[RunRecord],
    quick: bool,
    traj_path: Path,
    sampled: SampledTrajectory,
    f_load: np.ndarray,
    f_free: np.ndarray,
    duration: float,
    events: list[float],
    best_key: str | None,
) -> dict[str, Any]:
    """The runs and the table of delays per setting."""
    th0 = rows_data[thesis_key]["events"][0]
    rep.heading("Runs")
    rep.text(
        f"{len(runs)} run(s) ({run_layout(ctx.mode, quick, parallel='two rigs at a time')}, {ctx.mode}), PI only, OATF off, along a small closed loop of "
        f"irregular square teeth ({len(sampled.joints.phi) / FS_HZ:.1f} s per lap at {SPEED:g} in/s; `records/{traj_path.name}`), where the true first mode stays in "
        f"{f_load.min():.3f}–{f_load.max():.3f} Hz with the payload and {f_free.min():.3f}–{f_free.max():.3f} Hz without (model, along the set-points). "
        f"The payload starts attached and is released / picked up again at {', '.join(f'{e:g}' for e in events)} s (`RALF_SCENARIO`); the run ends at {duration:g} s. "
        f"Releasing it steps the true first mode by {th0['step_pct']:+.1f} % ({th0['true_before_hz']:.3f} → {th0['true_after_hz']:.3f} Hz). "
        f"The identified first pole (held between interrupts, whatever its confidence) is compared with the plant's ground truth through a centred "
        f"±{MEDIAN_HALF_S:g} s running median: **delay to 2 %** = the first time after an event from which the running median stays within "
        f"{100 * TOLERANCE:g} % of the true first mode for {HOLD_S:g} s (∞: not before the next event); **delay to stay within 2 %** = the time "
        f"after which it stays within {100 * TOLERANCE:g} % up to the next event (up to {MEDIAN_HALF_S:g} s before it, where the centred median "
        "starts to see it; ∞: outside there); **delay to 50 %** = the first time it crosses "
        "half-way from the old to the new true frequency (only when it started on the old side)."
    )
    rows = []
    for k, d in rows_data.items():
        rows.append(
            [
                _label(d) + (" (thesis)" if (d["fft_width"], d["alpha"], d["identifier"]) == THESIS_SETTING else "") + (" **best**" if k == best_key else ""),
                d["window_s"],
                d["averaging_span_s"],
                d["first_estimate_s"],
                f"{d['settled_events']}/{len(events)}",
                d["median_settle_2pct_s"],
                d["max_settle_2pct_s"],
                f"{d['stayed_events']}/{len(events)}",
                d["median_stays_2pct_s"],
                d["median_delay_50pct_s"],
                100 * d["median_rel_error_end"],
                d["median_confidence"],
            ]
        )
    rep.table(
        [
            "setting (l = 20)",
            "window N/fs (s)",
            "averaged span (s)",
            "first estimate (s)",
            "events settled to 2 %",
            "median delay to 2 % (s)",
            "longest (s)",
            "events staying within 2 % up to the next",
            "median delay to stay within 2 % (s)",
            "median delay to 50 % (s)",
            "error at the end (%)",
            "median confidence",
        ],
        rows,
        caption="Per setting, over the events; averaged span = (N + l(1/α − 1)) / fs; error: median |f_id − f_true| / f_true over the last 8 s",
        digits=3,
    )
    return th0


def _events_section(
    rep: Report, rows_data: dict[str, dict[str, Any]], runs: list[RunRecord], settings: tuple[tuple[int, float, str], ...], events: list[float]
) -> None:
    """The table of every event and the tracks figure."""
    ev_rows = []
    for d in rows_data.values():
        for e in d["events"]:
            ev_rows.append(
                [
                    _label(d),
                    e["at_s"],
                    e["kind"],
                    e["step_pct"],
                    e["settle_2pct_s"],
                    e["stays_2pct_s"],
                    e["delay_50pct_s"],
                    e["first_raw_in_band_s"],
                    100 * e["median_rel_error_before"],
                ]
            )
    rep.table(
        [
            "setting",
            "event (s)",
            "payload",
            "true step (%)",
            "delay to 2 % (s)",
            "delay to stay within 2 % (s)",
            "delay to 50 % (s)",
            "first raw estimate in band (s)",
            "error before (%)",
        ],
        ev_rows,
        caption="Every event (NaN: the running median was not on the old side at the event)",
        digits=3,
    )
    fig = _tracks_figure(runs, rows_data, settings, events)
    rep.figure(
        fig,
        "id_lag_tracks.png",
        "Identified first pole (dots), its centred running median (red), the true first mode (black) and the 2 % band around it, per setting; events at the dotted lines.",
    )


def _checks_and_thesis(
    rep: Report, rows_data: dict[str, dict[str, Any]], thesis_key: str, events: list[float], th0: dict[str, Any], best_key: str | None, quick: bool
) -> None:
    """The checks and the comparison with the thesis."""
    th = rows_data[thesis_key]
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


def _report_arx(rep: Report, arx_replay: dict[str, Any], events: list[float], quick: bool) -> None:
    """The ARX replayed from the record: as run, reset at the event, with its change detector and its regime banks."""
    rep.heading("The recursive ARX with a change detector that knows the change time")
    rep.text(
        "The DSP's ARX model replayed from the controller's record (the DSP's inputs and outputs sample for sample, the same batches, "
        "the same configuration), as run and with a reset at each payload event the plant's record shows: before the batch that holds "
        f"the event, the model's information is discounted by γ = {ORACLE_GAMMA:g} (`RecursiveArx.discount`, the square-root information "
        "form of a covariance reset). No detector can know the change time better, so the second row bounds what a CUSUM or "
        "likelihood-ratio reset of this model can gain; the estimate is held from two batches after its batch, as the controller holds it."
    )
    _arx_table(rep, arx_replay, events)
    _arx_regime_checks(rep, arx_replay, events)
    _arx_carried_bank(rep, arx_replay, quick)


def _arx_table(rep: Report, arx_replay: dict[str, Any], events: list[float]) -> None:
    """The table of the replayed ARX's delays: as run, reset at the event, change detector, regime banks."""
    rrows = []
    for label, dd in (
        ("ARX as run (replay)", arx_replay["as_run"]),
        (f"ARX, reset at the event (γ {ORACLE_GAMMA:g})", arx_replay["reset_at_the_event"]),
        ("ARX with its change detector (`arx_change_detection`)", arx_replay["change_detection"]),
        (f"ARX with a regime bank (`arx_regime_bank` {REGIME_BANK})", arx_replay["regime_bank"]),
        *(
            [("ARX with the regime bank of a calibration run carried in (`arx_regime_bank_file`)", arx_replay["regime_bank_carried"])]
            if "regime_bank_carried" in arx_replay
            else []
        ),
    ):
        rrows.append(
            [
                label,
                f"{dd['settled_events']}/{len(events)}",
                dd["median_settle_2pct_s"],
                dd["max_settle_2pct_s"],
                ", ".join(f"{e['settle_2pct_s']:.1f}" for e in dd["events"]),
                f"{dd['stayed_events']}/{len(events)}",
                ", ".join(f"{e['stays_2pct_s']:.1f}" for e in dd["events"]),
                100 * dd["median_rel_error_end"],
            ]
        )
    rep.table(
        [
            "model",
            "events settled to 2 %",
            "median delay to 2 % (s)",
            "longest (s)",
            "per event (s)",
            "events staying within 2 %",
            "delay to stay, per event (s)",
            "error at the end (%)",
        ],
        rrows,
        caption="The ARX replayed from the record: as run, with a reset at the true event times, with its own change detector, "
        "with a bank of regimes it learned on line (a remembered regime helps only at events whose regime was seen before: not the "
        "first), and with the bank a calibration run of the same rig learned (another noise seed) loaded before the first batch",
        digits=3,
    )


def _arx_regime_checks(rep: Report, arx_replay: dict[str, Any], events: list[float]) -> None:
    """The change detector's and the regime bank's switches, and the checks on the replay and the regime bank."""
    rep.text(
        "The change detector (`RecursiveArx`, CUSUM of the log a-priori error level, discount γ at an alarm) fired at "
        + (", ".join(f"{a:.1f}" for a in arx_replay["change_alarms_s"]) or "no time")
        + " s (events at "
        + ", ".join(f"{e:g}" for e in events)
        + " s). The regime bank (`arx_regime_bank`: snapshots of the model's own settled information, stored when calm; the live "
        "model becomes a remembered one of another regime when that one's a-priori errors on the batches are markedly lower) switched at "
        + (", ".join(f"{a:.1f}" for a in arx_replay["regime_switches_s"]) or "no time")
        + " s."
    )
    rep.check(
        "the ARX replayed from the record reproduces the DSP's identified first pole",
        arx_replay["max_difference_to_the_record_hz"] <= 1e-9,
        f"largest difference {arx_replay['max_difference_to_the_record_hz']:.3g} Hz",
    )
    seen = arx_replay["regime_bank"]["events"][1:]  # the first event leads into a regime the run has not shown yet
    if seen:
        settle_seen = [e["settle_2pct_s"] for e in seen]
        rep.check(
            f"with the regime bank: within 2 % in ≤ {GOAL_S:g} s after the payload steps into a regime seen before "
            "(median over those events; the first event's regime is new to the model)",
            float(np.median(settle_seen)) <= GOAL_S,
            "per event " + ", ".join(f"{x:.1f}" for x in settle_seen) + f" s ({sum(x <= GOAL_S for x in settle_seen)} of {len(seen)} ≤ {GOAL_S:g} s); "
            f"the first event {arx_replay['regime_bank']['events'][0]['settle_2pct_s']:.1f} s",
        )
    first = arx_replay["regime_bank"]["events"][0]["settle_2pct_s"]
    rep.known_limit(
        f"the ARX learning in the run alone settles within 2 % in ≤ {GOAL_S:g} s the first time the payload steps into a regime "
        "(a regime it has not met cannot be remembered; a bank carried from a calibration run removes the first meeting)",
        f"the first event {first:.1f} s",
        first <= GOAL_S,
    )


def _arx_carried_bank(rep: Report, arx_replay: dict[str, Any], quick: bool) -> None:
    """The regime bank carried from the calibration run, and its check (full runs)."""
    if "regime_bank_carried" in arx_replay:
        carried = arx_replay["regime_bank_carried"]
        cb = arx_replay["carried_bank"]
        rep.text(
            "The calibration run: the same rig and trajectory, another sensor-noise seed, and the payload events "
            f"{CALIBRATION_SHIFT_S:g} s later than this run's (at "
            + ", ".join(f"{at:g}" for at in cb["events_s"])
            + " s: midway between them, so its regimes are learned at other points of the loop); its ARX (replayed with "
            f"`arx_regime_bank` {REGIME_BANK}) ended with {cb['regimes']} regime(s), signatures "
            + "; ".join(" / ".join(f"{f:.2f}" for f in sig) + " Hz" for sig in cb["signatures_hz"])
            + ". Loaded before this run's first batch (as `RALF_ARX_REGIME_BANK_FILE` loads the bank an earlier run wrote), the model "
            "switched at " + (", ".join(f"{a:.1f}" for a in arx_replay["carried_switches_s"]) or "no time") + " s."
        )
        settle_all = [e["settle_2pct_s"] for e in carried["events"]]
        stays = [e["stays_2pct_s"] for e in carried["events"]]
        if quick:
            rep.text(
                "(--quick: the calibration run is too short for its bank to store both regimes, so the carried bank is reported but "
                "not checked; the full run checks it.)"
            )
        else:
            rep.check_every(
                f"with the regime bank carried from a calibration run: within 2 % in ≤ {GOAL_S:g} s after every payload step, the first included",
                [x <= GOAL_S for x in settle_all],
                "per event " + ", ".join(f"{x:.1f}" for x in settle_all) + " s (delay to stay within 2 %: " + ", ".join(f"{x:.1f}" for x in stays) + " s); "
                f"learned in the run alone, the first event {arx_replay['regime_bank']['events'][0]['settle_2pct_s']:.1f} s",
            )


def _tracks_figure(runs: list[RunRecord], rows: dict[str, dict[str, Any]], settings: tuple[tuple[int, float, str], ...], events: list[float]) -> Figure:
    fig = new_figure(11.0, 2.1 * len(runs) + 0.6)
    axes = np.atleast_1d(fig.subplots(len(runs), 1, sharex=True))
    for ax, (n, a, m), r in zip(axes, settings, runs):
        d = rows[_name(n, a, m)]
        t = r.t_s
        true1 = r.true_mode_hz(t, 0)
        ax.fill_between(t, true1 * (1 - TOLERANCE), true1 * (1 + TOLERANCE), color="0.85", lw=0)
        ax.plot(t, true1, color="k", lw=1.0)
        ax.plot(t[::10], np.asarray(r.columns["f_id_hz"])[::10], ".", ms=1.5, color="tab:blue")
        ax.plot(d["median_series"]["t_s"], d["median_series"]["f_hz"], color="tab:red", lw=1.0)
        for e in events:
            ax.axvline(e, color="k", ls=":", lw=0.8)
        ax.set_ylim(true1.min() * 0.85, true1.max() * 1.15)
        ax.set_ylabel("Hz")
        ax.set_title(
            f"{_label(d)}: delay to 2 % "
            + ", ".join(f"{e['settle_2pct_s']:.1f}" for e in d["events"])
            + " s; to 50 % "
            + ", ".join(f"{e['delay_50pct_s']:.1f}" for e in d["events"])
            + " s",
            fontsize=8,
        )
        ax.grid(True, lw=0.3)
    axes[-1].set_xlabel("time (s)")
    return fig


def _delay_figure(rows: dict[str, dict[str, Any]], n_events: int) -> Figure:
    fig = new_figure(10.0, 3.8)
    ax1, ax2 = fig.subplots(1, 2)
    keys = list(rows)
    x = np.arange(len(keys))
    d2 = [rows[k]["median_settle_2pct_s"] for k in keys]
    d5 = [rows[k]["median_delay_50pct_s"] for k in keys]
    ax1.bar(x - 0.2, [v if math.isfinite(v) else np.nan for v in d2], 0.4, label="to 2 % (median)", color="tab:blue")
    ax1.bar(x + 0.2, [v if math.isfinite(v) else np.nan for v in d5], 0.4, label="to 50 % (median)", color="tab:orange")
    for i, k in enumerate(keys):
        if not math.isfinite(d2[i]):
            ax1.annotate("∞", (i - 0.2, 0), ha="center", va="bottom")
        ax1.annotate(f"{rows[k]['settled_events']}/{n_events}", (i - 0.2, 0), xytext=(0, -22), textcoords="offset points", ha="center", fontsize=6)
    labels = [
        (
            f"N {rows[k]['fft_width']}\nα {rows[k]['alpha']:g}"
            + {"etfe": "", "etfe-welch": "\nWelch+fit", "etfe-transient": "\ntransient fit"}.get(rows[k]["identifier"], "")
            if rows[k]["identifier"] != "arx"
            else "ARX"
        )
        + ("\n(thesis)" if (rows[k]["fft_width"], rows[k]["alpha"], rows[k]["identifier"]) == THESIS_SETTING else "")
        for k in keys
    ]
    ax1.set_xticks(x, labels, fontsize=7)
    ax1.set_ylabel("delay after the event (s)")
    ax1.legend(fontsize=7)
    ax1.grid(True, axis="y", lw=0.3)
    ax2.bar(x, [100 * rows[k]["median_rel_error_end"] for k in keys], 0.6, color="tab:green")
    ax2.axhline(100 * TOLERANCE, color="k", ls=":", lw=0.8)
    ax2.set_xticks(x, labels, fontsize=7)
    ax2.set_ylabel("median |error| at the end (%)")
    ax2.grid(True, axis="y", lw=0.3)
    return fig
