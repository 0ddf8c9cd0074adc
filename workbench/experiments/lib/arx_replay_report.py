"""The report section of an ARX replay study (:func:`.arx_replay.arx_replays`): what was replayed, the delays of
each variant, the change detector's alarms and the regime banks' switches."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from workbench.experiments.lib.arx_replay import ORACLE_GAMMA
from workbench.experiments.report import Report

__all__ = ["arx_replay_section", "carried_bank_text"]


def arx_replay_section(rep: Report, replay: dict[str, Any], events: Sequence[float], regime_bank: int) -> None:
    """Heading, method, the table of delays per variant, and where the detector fired and the bank switched."""
    rep.heading("The recursive ARX with a change detector that knows the change time")
    rep.text(
        "The DSP's ARX model replayed from the controller's record (the DSP's inputs and outputs sample for sample, the same batches, "
        "the same configuration), as run and with a reset at each payload event the plant's record shows: before the batch that holds "
        f"the event, the model's information is discounted by γ = {ORACLE_GAMMA:g} (`RecursiveArx.discount`, the square-root information "
        "form of a covariance reset). No detector can know the change time better, so the second row bounds what a CUSUM or "
        "likelihood-ratio reset of this model can gain; the estimate is held from two batches after its batch, as the controller holds it."
    )
    variants = [
        ("ARX as run (replay)", "as_run"),
        (f"ARX, reset at the event (γ {ORACLE_GAMMA:g})", "reset_at_the_event"),
        ("ARX with its change detector (`arx_change_detection`)", "change_detection"),
        (f"ARX with a regime bank (`arx_regime_bank` {regime_bank})", "regime_bank"),
        ("ARX with the regime bank of a calibration run carried in (`arx_regime_bank_file`)", "regime_bank_carried"),
    ]
    rows = []
    for label, key in variants:
        if key not in replay:
            continue
        dd = replay[key]
        rows.append(
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
        rows,
        caption="The ARX replayed from the record: as run, with a reset at the true event times, with its own change detector, "
        "with a bank of regimes it learned on line (a remembered regime helps only at events whose regime was seen before: not the "
        "first), and with the bank a calibration run of the same rig learned (another noise seed) loaded before the first batch",
        digits=3,
    )
    rep.text(
        "The change detector (`RecursiveArx`, CUSUM of the log a-priori error level, discount γ at an alarm) fired at "
        + (", ".join(f"{a:.1f}" for a in replay["change_alarms_s"]) or "no time")
        + " s (events at "
        + ", ".join(f"{e:g}" for e in events)
        + " s). The regime bank (`arx_regime_bank`: snapshots of the model's own settled information, stored when calm; the live "
        "model becomes a remembered one of another regime when that one's a-priori errors on the batches are markedly lower) switched at "
        + (", ".join(f"{a:.1f}" for a in replay["regime_switches_s"]) or "no time")
        + " s."
    )


def carried_bank_text(rep: Report, replay: dict[str, Any], shift_s: float, regime_bank: int) -> None:
    """The calibration run whose bank was carried in (events ``shift_s`` later), its regimes and the switches it caused."""
    cb = replay["carried_bank"]
    rep.text(
        "The calibration run: the same rig and trajectory, another sensor-noise seed, and the payload events "
        f"{shift_s:g} s later than this run's (at "
        + ", ".join(f"{at:g}" for at in cb["events_s"])
        + " s: midway between them, so its regimes are learned at other points of the loop); its ARX (replayed with "
        f"`arx_regime_bank` {regime_bank}) ended with {cb['regimes']} regime(s), signatures "
        + "; ".join(" / ".join(f"{f:.2f}" for f in sig) + " Hz" for sig in cb["signatures_hz"])
        + ". Loaded before this run's first batch (as `RALF_ARX_REGIME_BANK_FILE` loads the bank an earlier run wrote), the model "
        "switched at " + (", ".join(f"{a:.1f}" for a in replay["carried_switches_s"]) or "no time") + " s."
    )
