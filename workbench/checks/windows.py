"""The part of a signal a check looks at, and why it may be too little to judge."""

from __future__ import annotations

import numpy as np

from workbench.checks.result import fmt
from workbench.checks.signal import Signal


def window(sig: Signal, from_s: float | None, min_samples: int) -> tuple[Signal, str | None]:
    """``sig`` from ``from_s`` on, and the reason it is too short to judge (None when it is not)."""
    part = sig.since(from_s)
    if len(part) < min_samples:
        where = f" from {fmt(from_s)} s on" if from_s is not None else ""
        return part, f"{sig.name} has {len(part)} samples{where}, at least {min_samples} needed"
    return part, None


def non_finite(sig: Signal) -> str | None:
    """Why a signal's non-finite samples make it unmeasurable (None when all are finite)."""
    bad = int(np.count_nonzero(~np.isfinite(sig.values)))
    return f"{sig.name} has {bad} non-finite samples of {len(sig)}" if bad else None


def label(check: str, *signals: Signal | str) -> str:
    """A result's name: the check and its signals, ``overshoot_below(phi1)``."""
    return f"{check}({', '.join(s if isinstance(s, str) else s.name for s in signals)})"
