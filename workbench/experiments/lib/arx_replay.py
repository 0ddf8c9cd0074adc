"""The DSP's recursive ARX replayed from a controller record, with what the run did not have: a reset at the
true change time, its change detector, a regime bank learned in the run or carried in from another run
(docs/identification.md §5c-5d).

The controller's record holds the DSP's inputs and outputs sample for sample
(the D/A commands ``u1_v``, ``u2_v`` and the deflections ``defl1_in``,
``defl2_in``); batch ``k`` is samples ``[k l, (k + 1) l)``, the model is the
one ``method='arx'`` builds (:func:`dsp_service.identifier.arx_config`),
restarted before the first batch as the controller's reset at the start does.
The controller holds batch ``k``'s estimate from tick ``(k + 2) l`` on
(:func:`held`), so a replay is compared with the record tick for tick
(:func:`replay_matches_record`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from dsp_service.arx import RecursiveArx, RegimeBankState
from dsp_service.identifier import IdentifierConfig, arx_config
from workbench.experiments.analysis import THESIS_BATCH_SIZE
from workbench.experiments.lib.identification_delay import payload_switch_times, series_delays, steady_share
from workbench.hil import RunRecord

__all__ = ["ORACLE_GAMMA", "arx_replays", "held", "learn_bank", "replay_arx", "replay_matches_record"]

ORACLE_GAMMA = 1e-3
"""The weight the replayed ARX's reset at the true event time leaves on the data before it (``RecursiveArx.discount``)."""


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


def replay_arx(
    res: RunRecord,
    batch_size: int,
    discount_at_s: Sequence[float] = (),
    gamma: float = ORACLE_GAMMA,
    cfg: IdentifierConfig | None = None,
    bank: RegimeBankState | None = None,
) -> tuple[np.ndarray, list[float]]:
    """The first pole after each batch, and the end times of the batches at which the change detector fired
    (``cfg.arx_change_detection``) or the regime bank switched to a remembered model (``cfg.arx_regime_bank``).
    ``discount_at_s``: before the batch that holds each of these times, the model's information is discounted
    by ``gamma`` (:meth:`RecursiveArx.discount`): a change detector that knows the change time. ``bank``: the
    regime bank another run learned (:func:`learn_bank`), loaded before the first batch as the DSP loads
    ``arx_regime_bank_file``."""
    first_pole, alarms, _model = _replayed_arx(res, batch_size, cfg, bank, discount_at_s, gamma)
    return first_pole, alarms


def learn_bank(res: RunRecord, batch_size: int, cfg: IdentifierConfig) -> RegimeBankState:
    """The regime bank the ARX of ``cfg`` holds at the end of ``res`` (replayed from its record): what
    ``arx_regime_bank_file`` would carry out of that run."""
    return _replayed_arx(res, batch_size, cfg, None)[2].bank_state()


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


def arx_replays(
    res: RunRecord,
    events: Sequence[float],
    sample_rate_hz: float,
    regime_bank: int,
    calibration: RunRecord | None = None,
    calibration_events_s: Sequence[float] = (),
    batch_size: int = THESIS_BATCH_SIZE,
) -> dict[str, Any]:
    """One run's ARX replayed (:func:`replay_arx`) as run, reset at the payload switches the plant applied
    (γ :data:`ORACLE_GAMMA`), with its change detector, with a bank of ``regime_bank`` regimes learned in the
    run, and (``calibration``: another run of the same rig, its payload events at ``calibration_events_s``)
    with the bank that run learned carried in from the start; the delays of each after ``events`` (:func:`series_delays`, without the running medians)."""
    banked_cfg = IdentifierConfig(method="arx", sample_rate_hz=sample_rate_hz, arx_regime_bank=regime_bank)
    t_r, true_r = res.t_s, res.true_mode_hz(res.t_s, 0)
    replayed, _ = replay_arx(res, batch_size)
    reset, _ = replay_arx(res, batch_size, discount_at_s=payload_switch_times(res))
    detected, alarms = replay_arx(res, batch_size, cfg=IdentifierConfig(method="arx", sample_rate_hz=sample_rate_hz, arx_change_detection=True))
    banked, switches = replay_arx(res, batch_size, cfg=banked_cfg)
    out: dict[str, Any] = {
        "max_difference_to_the_record_hz": replay_matches_record(res, replayed, batch_size),
        "gamma": ORACLE_GAMMA,
        "as_run": series_delays(t_r, held(replayed, t_r.size, batch_size), true_r, events),
        "reset_at_the_event": series_delays(t_r, held(reset, t_r.size, batch_size), true_r, events),
        "change_detection": series_delays(t_r, held(detected, t_r.size, batch_size), true_r, events),
        "change_alarms_s": alarms,
        "regime_bank": series_delays(t_r, held(banked, t_r.size, batch_size), true_r, events),
        "regime_switches_s": switches,
    }
    keys = ["as_run", "reset_at_the_event", "change_detection", "regime_bank"]
    if calibration is not None:
        carried_bank = learn_bank(calibration, batch_size, banked_cfg)
        carried, carried_switches = replay_arx(res, batch_size, cfg=banked_cfg, bank=carried_bank)
        out["regime_bank_carried"] = series_delays(t_r, held(carried, t_r.size, batch_size), true_r, events)
        out["carried_switches_s"] = carried_switches
        out["carried_bank"] = {
            "regimes": carried_bank.regimes,
            "signatures_hz": carried_bank.signature.tolist(),
            "seed": calibration.settings["plant"].get("seed"),
            "events_s": list(calibration_events_s),
        }
        keys.append("regime_bank_carried")
    for key in keys:
        out[key].pop("median_series")  # the delays are the results; the series would triple the file
    out["steady_within_2pct"] = steady_share(t_r, held(replayed, t_r.size, batch_size), true_r, events)
    return out
