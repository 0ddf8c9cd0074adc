"""Helpers the plant tests share (imported by test modules; never import one test module from another)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.signal as ss

ROOT = Path(__file__).resolve().parents[2]
EDS = ROOT / "protocol" / "ralf_io.eds"
"""The node's shipped EDS."""

FS = 200.0
"""Sample rate of the plant records (Hz)."""


class FakeApp:
    """A plant stand-in: fixed analog volts, quantized by the current A/D."""

    def __init__(self, volts: tuple[float, ...] = (1.0, -2.5, 9.9, -10.0)) -> None:
        self.bits = 12
        self.volts = np.asarray(volts, dtype=float)
        self.saturated = np.zeros(4, dtype=bool)
        self.syncs: list[int] = []
        self.outputs: list[np.ndarray] = []
        self.watchdog: list[bool] = []
        self.adc_calls: list[int] = []

    @property
    def codes(self) -> np.ndarray:
        from protocol.can_map import ConverterScale

        return ConverterScale(self.bits).quantize(self.volts).counts

    def on_sync(self, counter: int) -> tuple[np.ndarray, np.ndarray]:
        self.syncs.append(counter)
        return self.codes, self.saturated.copy()

    def on_outputs(self, volts: np.ndarray) -> None:
        self.outputs.append(np.array(volts))

    def on_watchdog(self, tripped: bool) -> None:
        self.watchdog.append(tripped)

    def on_adc_bits(self, bits: int) -> None:
        self.adc_calls.append(bits)
        self.bits = bits


def mimo_h1(u: np.ndarray, y: np.ndarray, nper: int = 1024) -> tuple[np.ndarray, np.ndarray]:
    """H[f, i, j] from input i to output j (conjugates as in scipy's csd)."""
    f, p11 = ss.welch(u[:, 0], FS, nperseg=nper)
    _, p22 = ss.welch(u[:, 1], FS, nperseg=nper)
    _, p12 = ss.csd(u[:, 0], u[:, 1], FS, nperseg=nper)
    p21 = np.conj(p12)
    den = p11 * p22 - np.abs(p12) ** 2
    H = np.empty((f.size, 2, 2), dtype=complex)
    for j in range(2):
        _, p1y = ss.csd(u[:, 0], y[:, j], FS, nperseg=nper)
        _, p2y = ss.csd(u[:, 1], y[:, j], FS, nperseg=nper)
        H[:, 0, j] = (p1y * p22 - p12 * p2y) / den
        H[:, 1, j] = (p2y * p11 - p21 * p1y) / den
    return f, H


def interior_peak_hz(f: np.ndarray, mag: np.ndarray, lo: float, hi: float) -> float:
    """Frequency of the largest local maximum in [lo, hi], parabolic on log |H|."""
    idx = np.flatnonzero((f >= lo) & (f <= hi))
    i = idx[np.argmax(mag[idx])]
    assert idx[0] < i < idx[-1], "no interior peak"
    a, b, c = np.log(mag[i - 1 : i + 2])
    return float(f[i] + 0.5 * (a - c) / (a - 2 * b + c) * (f[1] - f[0]))
