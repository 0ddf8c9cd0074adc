"""Report text and tables of the delays after discontinuous changes (:mod:`.identification_delay`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from workbench.experiments.lib.identification_delay import HOLD_S, MEDIAN_HALF_S, TOLERANCE
from workbench.experiments.report import Report

__all__ = ["definitions_text", "event_table"]


def definitions_text() -> str:
    """How the delays are read off the identified series (one paragraph of Markdown)."""
    return (
        "The identified first pole (held between interrupts, whatever its confidence) is compared with the plant's ground truth through a centred "
        f"±{MEDIAN_HALF_S:g} s running median: **delay to 2 %** = the first time after an event from which the running median stays within "
        f"{100 * TOLERANCE:g} % of the true first mode for {HOLD_S:g} s (∞: not before the next event); **delay to stay within 2 %** = the time "
        f"after which it stays within {100 * TOLERANCE:g} % up to the next event (up to {MEDIAN_HALF_S:g} s before it, where the centred median "
        "starts to see it; ∞: outside there); **delay to 50 %** = the first time it crosses "
        "half-way from the old to the new true frequency (only when it started on the old side)."
    )


def event_table(rep: Report, labelled: Sequence[tuple[str, Mapping[str, Any]]]) -> None:
    """One row per event of every labelled series' delays (:func:`.identification_delay.series_delays`)."""
    keys = ("at_s", "kind", "step_pct", "settle_2pct_s", "stays_2pct_s", "delay_50pct_s", "first_raw_in_band_s")
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
        [[label, *(e[c] for c in keys), 100 * e["median_rel_error_before"]] for label, d in labelled for e in d["events"]],
        caption="Every event (NaN: the running median was not on the old side at the event)",
        digits=3,
    )


SUMMARY_COLUMNS = (
    ("events settled to 2 %", "settled_events"),
    ("median delay to 2 % (s)", "median_settle_2pct_s"),
    ("longest (s)", "max_settle_2pct_s"),
    ("events staying within 2 % up to the next", "stayed_events"),
    ("median delay to stay within 2 % (s)", "median_stays_2pct_s"),
    ("median delay to 50 % (s)", "median_delay_50pct_s"),
)
"""The summary of a series' delays over the events, as table columns (header, key); counts are shown as k/n."""


def summary_table(
    rep: Report,
    labelled: Sequence[tuple[str, Mapping[str, Any]]],
    n_events: int,
    *,
    before: Sequence[tuple[str, str]] = (),
    after: Sequence[tuple[str, str]] = (),
    first_header: str = "setting",
    caption: str = "",
) -> None:
    """One row per labelled series: the columns ``before`` (header, key), the summary over its ``n_events``
    events (:data:`SUMMARY_COLUMNS`), the error at the end (%) and the columns ``after``."""
    rows = []
    for label, d in labelled:
        cells = [d[k] if not k.endswith("_events") else f"{d[k]}/{n_events}" for _h, k in (*before, *SUMMARY_COLUMNS)]
        rows.append([label, *cells, 100 * d["median_rel_error_end"], *(d[k] for _h, k in after)])
    headers = [first_header, *(h for h, _k in (*before, *SUMMARY_COLUMNS)), "error at the end (%)", *(h for h, _k in after)]
    rep.table(headers, rows, caption=caption or None, digits=3)
