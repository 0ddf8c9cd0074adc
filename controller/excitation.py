"""Persistent excitation: a small multisine dither on the valve commands (opt-in).

The identifier can only learn what the commands excite.  Along the
trajectories the valve commands follow the set-points, whose power at the
first mode (3–6 Hz) is three decades below that at 1 Hz; the mode is rung by
the trajectory's corners only (docs/identification.md §3a, §5), so after a
change of the plant the new first mode stays invisible until the next corner.
A dither puts that information into the data all the time: each valve command
gets a small periodic multisine added after the PI (and an inner OATF), before
the D/A, so the DSP's inputs (the D/A commands) carry it and the OATF does not
notch it out.

The table is computed once, with numpy, from its settings alone (amplitude,
band, period, seed): a flat amplitude spectrum on every DFT bin of the period
inside the band, random phases drawn per valve from ``numpy.random.default_rng(seed)``
(independent phases: the two valves' dithers are uncorrelated over a period,
so the 2×2 input spectrum stays full rank even where the trajectory's own
commands are collinear), scaled to the requested RMS per valve.  The control
law adds ``table[tick % period]`` in its Python form and its compiled form
alike (the same float64 additions on the same table), so both stay bit for
bit equal; with amplitude 0 (the default) nothing is added and the law is
unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

__all__ = ["DitherConfig", "dither_table"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DitherConfig:
    """The dither's settings (``RALF_DITHER``; amplitude 0: off)."""

    amplitude_v: float = 0.0
    """RMS of each valve's dither (V, at the D/A); 0 disables it."""
    band_hz: tuple[float, float] = (2.0, 7.0)
    """Frequencies it covers: every DFT bin of the period in ``[lo, hi]`` (the first mode's range along the loops)."""
    period_ticks: int = 4096
    """Length of the periodic table (ticks); its bin spacing is ``1 / (period_ticks · Ts)``."""
    seed: int = 0
    """Seed of the random phases."""

    def __post_init__(self) -> None:
        lo, hi = self.band_hz
        if not (np.isfinite(self.amplitude_v) and self.amplitude_v >= 0.0):
            raise ValueError(f"dither amplitude must be finite and ≥ 0, got {self.amplitude_v!r}")
        if not (0.0 < lo < hi):
            raise ValueError(f"dither band must be 0 < lo < hi, got {self.band_hz!r}")
        if self.period_ticks < 16:
            raise ValueError(f"dither period must be at least 16 ticks, got {self.period_ticks}")

    @property
    def enabled(self) -> bool:
        return self.amplitude_v > 0.0


def dither_table(config: DitherConfig, sample_period_s: float) -> FloatArray:
    """The dither, ``(period_ticks, 2)`` volts per tick and valve (zeros when off).

    Raises ``ValueError`` when the band holds no bin of the period or lies above Nyquist."""
    n = config.period_ticks
    out = np.zeros((n, 2))
    if not config.enabled:
        return out
    lo, hi = config.band_hz
    f = np.fft.rfftfreq(n, sample_period_s)
    band = (f >= lo) & (f <= hi) & (f > 0.0) & (f < 0.5 / sample_period_s)
    if not band.any():
        raise ValueError(f"the dither band {config.band_hz!r} Hz holds no bin of a {n}-tick period at {1.0 / sample_period_s:g} Hz")
    rng = np.random.default_rng(config.seed)
    for ch in range(2):
        spec = np.zeros(f.size, dtype=complex)
        spec[band] = np.exp(2j * np.pi * rng.random(int(band.sum())))
        x = np.fft.irfft(spec, n)
        out[:, ch] = x * (config.amplitude_v / float(np.sqrt(np.mean(x * x))))
    return out
