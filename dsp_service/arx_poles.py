"""The modal poles of the recursive ARX model (:class:`.arx.RecursiveArx`): the roots of its common
denominator with their damping and modal strength."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsp_service.arx_config import ArxConfig


@dataclass(frozen=True)
class ArxPole:
    """One pole of the identified denominator."""

    frequency_hz: float  #: natural frequency |s|/2π
    damping_ratio: float  #: −Re s / |s|
    strength: float  #: modal peak √(Σ|r_ij|²)/(1 − |z|)
    relative_strength: float  #: strength / the strongest kept pole's


def modal_poles(cfg: ArxConfig, a: NDArray[np.float64], bs: NDArray[np.float64]) -> tuple[ArxPole, ...]:
    """The modal poles of the model ``B_ij/A`` (``a`` = ``[1, a_1, …]``, ``bs`` the four ``[0, b_ij,1, …]``
    rows H11, H12, H21, H22, unscaled), strongest first or by frequency (``order_by``), at most ``max_poles``:
    the roots of ``A`` in the search band, stable, with ``0 < ζ < max_damping`` and at least
    ``min_relative_strength`` of the strongest (:mod:`.arx`'s module doc)."""
    c = cfg
    z = np.roots(a)
    if z.size == 0:
        return ()
    fs = c.model_rate_hz
    keep = (z.imag > 0) & (np.abs(z) < 1.0) & (np.abs(z) > 0)
    zk = z[keep]
    if zk.size == 0:
        return ()
    s = fs * np.log(zk)
    wn = np.abs(s)
    fn = wn / (2 * math.pi)
    zeta = -s.real / wn
    ok = (fn >= c.search_min_hz) & (fn <= c.search_max_hz) & (zeta > 0) & (zeta < c.max_damping)
    if not ok.any():
        return ()
    zk, fn, zeta = zk[ok], fn[ok], zeta[ok]
    # residue of B(q)/A(q), q = z⁻¹, at the pole: B(q_k) / Π_{m≠k} (1 − z_m q_k), q_k = 1/z_k,
    # with Π_{m≠k} (1 − z_m q_k) = −A'(q_k) / z_k  (A(q) = Π_m (1 − z_m q))
    qk = 1.0 / zk
    P = np.polynomial.polynomial
    da = P.polyder(a)  # a is [1, a_1, …]: coefficients in ascending powers of q
    den = -P.polyval(qk, da) / zk
    num = P.polyval(qk, bs.T)  # (4, K); bs (4, nb + 1), ascending in q
    strength = np.sqrt(np.sum(np.abs(num / den) ** 2, axis=0)) / np.maximum(1.0 - np.abs(zk), 1e-12)
    top = float(strength.max())
    rel = strength / top if top > 0 else np.zeros_like(strength)
    order = np.argsort(fn) if c.order_by == "frequency" else np.argsort(-strength)
    out = [ArxPole(float(fn[k]), float(zeta[k]), float(strength[k]), float(rel[k])) for k in order if rel[k] >= c.min_relative_strength]
    return tuple(out[: c.max_poles])
