"""Synthetic 2-input 2-output modal system for the identifier tests (deterministic, seeded).

``H_ij(s) = Σ_r R_r[i, j] ω_r² / (s² + 2 ζ_r ω_r s + ω_r²)`` (input i → output j),
discretised exactly at the poles (zero-order hold) and simulated with
``scipy.signal.lfilter``. The reference ("true") response is the discrete
system's own frequency response, so estimation error is all that remains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal
from numpy.typing import NDArray

FS = 200.0
MODES = ((3.6, 0.09), (9.0, 0.05))  # (f_n Hz, ζ)
# residues R_r[i, j]: mode r, input i, output j (all positive so H_tot shows both peaks)
RESIDUES = (
    np.array([[1.0, 0.6], [0.5, 0.8]]),
    np.array([[0.25, 0.4], [0.35, 0.2]]),
)


def modal_tf(modes: tuple[tuple[float, float], ...], residues: tuple[float, ...]) -> tuple[NDArray, NDArray]:
    """Continuous (num, den) of ``Σ_r R_r ω_r²/(s² + 2ζ_r ω_r s + ω_r²)``."""
    num = np.zeros(1)
    den = np.ones(1)
    for (fn, z), r in zip(modes, residues):
        wn = 2 * np.pi * fn
        n_r, d_r = np.array([r * wn * wn]), np.array([1.0, 2 * z * wn, wn * wn])
        num = np.polyadd(np.polymul(num, d_r), np.polymul(n_r, den))
        den = np.polymul(den, d_r)
    return num, den


@dataclass(frozen=True)
class DiscreteSystem:
    """Four discrete transfer functions ``tf[i][j]`` = (b, a), input i → output j."""

    tf: tuple[tuple[tuple[NDArray, NDArray], ...], ...]
    fs: float

    def simulate(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Outputs ``(2, n)`` for inputs ``(2, n)``."""
        y = np.zeros_like(u)
        for i in range(2):
            for j in range(2):
                b, a = self.tf[i][j]
                y[j] += scipy.signal.lfilter(b, a, u[i])
        return y

    def response(self, freqs: NDArray[np.float64]) -> NDArray[np.complex128]:
        """True ``H`` ``(4, len(freqs))`` rows H11, H12, H21, H22."""
        rows = []
        for i in range(2):
            for j in range(2):
                b, a = self.tf[i][j]
                rows.append(scipy.signal.freqz(b, a, worN=freqs, fs=self.fs)[1])
        return np.array(rows)


def make_system(
    modes: tuple[tuple[float, float], ...] = MODES,
    residues: tuple[NDArray, ...] = RESIDUES,
    fs: float = FS,
) -> DiscreteSystem:
    tf = []
    for i in range(2):
        row = []
        for j in range(2):
            num, den = modal_tf(modes, tuple(r[i, j] for r in residues))
            b, a, _ = scipy.signal.cont2discrete((num, den), 1.0 / fs, method="zoh")
            row.append((np.ravel(b), np.ravel(a)))
        tf.append(tuple(row))
    return DiscreteSystem(tuple(tf), fs)


def correlated_inputs(n: int, seed: int = 1, coupling: float = 0.9, delay: int = 3, fs: float = FS) -> NDArray[np.float64]:
    """``(2, n)`` band-limited inputs with low-frequency emphasis (like trajectory commands).

    ``u2 = coupling · u1(t − delay) + √(1 − coupling²) · (independent, same spectrum)``.
    The delay makes the cross-spectrum P12 complex (dynamic correlation),
    which is what distinguishes P12 from P21 in the solve. With the defaults
    the correlation coefficient of u1 and u2 is about 0.7.
    """
    rng = np.random.default_rng(seed)
    bl, al = scipy.signal.butter(4, 40.0, fs=fs)
    w = scipy.signal.lfilter(bl, al, rng.standard_normal((2, n + delay)), axis=-1)
    b1, a1 = scipy.signal.butter(1, 3.0, fs=fs)
    x = 8.0 * scipy.signal.lfilter(b1, a1, w, axis=-1) + w
    u1 = x[0, delay:]
    u2 = coupling * x[0, :n] + (1.0 - coupling**2) ** 0.5 * x[1, delay:]
    return np.vstack([u1, u2])


def dataset(n: int, seed: int = 1, coupling: float = 0.9, noise: float = 0.02) -> tuple[DiscreteSystem, NDArray[np.float64], NDArray[np.float64]]:
    """System, inputs and noisy outputs (white noise of ``noise`` × each output's std)."""
    sys_ = make_system()
    u = correlated_inputs(n, seed, coupling)
    y = sys_.simulate(u)
    rng = np.random.default_rng(seed + 1000)
    y += noise * y.std(axis=1, keepdims=True) * rng.standard_normal(y.shape)
    return sys_, u, y
