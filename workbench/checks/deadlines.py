"""Deadline misses in a row."""

from __future__ import annotations

import numpy as np

from workbench.checks.collect import collected
from workbench.checks.result import CheckResult, FigureData, Mark, Panel, Trace, fmt, invalid, judged
from workbench.checks.signal import Signal
from workbench.checks.windows import label, non_finite


def longest_streak(flags: np.ndarray) -> tuple[int, int]:
    """The longest run of non-zero entries: (its length, its first index; -1 when none)."""
    on = np.concatenate([[0], (np.asarray(flags) != 0).astype(np.int8), [0]])
    edges = np.diff(on)
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if starts.size == 0:
        return 0, -1
    lengths = ends - starts
    i = int(np.argmax(lengths))
    return int(lengths[i]), int(starts[i])


def no_deadline_miss_streak(misses: Signal, max_streak: int, *, name: str | None = None) -> CheckResult:
    """Were deadlines missed at most ``max_streak`` times in a row?

    ``misses`` is a per-tick or per-batch series (non-zero: missed; a record's miss
    column, ``interrupts.deadline_missed``), a counter's longest run in a row
    (``health.controller.deadline_miss_run_max``) or a count of misses
    (``counters.deadline_misses``, see
    :func:`workbench.checks.record_signals.deadline_misses`). A count bounds the
    streak: it passes when the count is within the limit, and compares nothing when
    it is not (their streak is unknown)."""
    title = name or label("no_deadline_miss_streak", misses)
    limit = float(max_streak)
    if len(misses) == 0 or (misses.kind in ("count", "run_max") and len(misses) != 1):
        return collected(invalid(title, f"{misses.name} has {len(misses)} samples", limit, "misses"))
    if (bad := non_finite(misses)) is not None:
        return collected(invalid(title, bad, limit, "misses"))
    if misses.kind == "count":
        count = int(misses.values[0])
        if count > max_streak:
            return collected(
                invalid(
                    title, f"{misses.name} counts {count} misses in all, which tells not their longest streak; give a per-tick miss series", limit, "misses"
                )
            )
        data = FigureData(
            title, (Panel("misses", hlines=((limit, f"limit {max_streak} in a row"),), marks=(Mark(float(misses.t[0]), count, f"{count} in all"),)),)
        )
        return collected(
            judged(
                title, True, count, limit, "misses", f"{misses.name}: {count} misses in all, so at most {count} in a row, against a limit of {max_streak}", data
            )
        )
    if misses.kind == "run_max":
        streak = int(misses.values[0])
        data = FigureData(
            title, (Panel("misses in a row", hlines=((limit, f"limit {max_streak}"),), marks=(Mark(float(misses.t[0]), streak, f"{streak} in a row"),)),)
        )
        return collected(
            judged(
                title, streak <= max_streak, streak, limit, "misses", f"{misses.name}: at most {streak} misses in a row against a limit of {max_streak}", data
            )
        )
    streak, start = longest_streak(misses.values)
    total = int(np.count_nonzero(misses.values))
    at = f" from {fmt(float(misses.t[start]))} s" if start >= 0 else ""
    data = FigureData(
        title,
        (
            Panel(
                "missed",
                traces=(Trace(misses.t, (misses.values != 0).astype(float), misses.name, "step"),),
                marks=(Mark(float(misses.t[start]), 1.0, f"{streak} in a row"),) if start >= 0 else (),
            ),
        ),
    )
    sentence = f"{streak} deadline misses in a row{at} ({total} of {len(misses)} missed) against a limit of {max_streak}"
    return collected(judged(title, streak <= max_streak, streak, limit, "misses", sentence, data, {"misses": float(total)}))
