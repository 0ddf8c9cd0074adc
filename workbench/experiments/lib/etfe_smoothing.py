"""The ETFE's smoothing window at other FFT widths: the thesis's width in Hz kept as N changes."""

from __future__ import annotations

__all__ = ["smoothing_window"]


def smoothing_window(n: int) -> int:
    """The thesis's 17 bins at N = 2048, scaled with N (the same width in Hz), odd, at least 5."""
    w = int(round(17 * n / 2048))
    w += 1 - w % 2
    return max(5, w)
