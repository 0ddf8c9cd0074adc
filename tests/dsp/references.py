"""References the DSP tests compare with, built here from numpy's linear algebra (never from the
code under test): the 2×2 transfer-function solve [2-21 … 2-24] and the VRM system [C-12]."""

from __future__ import annotations

import numpy as np

#: Rows of the averaged spectra (dsp_service.spectra): P11, P12, P1y1, P1y2, P22, P2y1, P2y2.
P11, P12, P1Y1, P1Y2, P22, P2Y1, P2Y2 = range(7)


def mimo_solve(S: np.ndarray, det_threshold: float = 1e-3, power_floor: float = 1e-12) -> tuple[np.ndarray, np.ndarray]:
    """``(H (4, K), valid (K,))``: per bin ``numpy.linalg.solve`` of ``P h_j = r_j`` with
    ``P = [[P11, P12], [P21, P22]]``, ``r_j = [P1yj, P2yj]``, rows H11, H12, H21, H22; a bin is valid
    when both input powers exceed ``power_floor`` × the mean input power and ``1 − γ²`` is at least
    ``det_threshold`` (invalid bins 0)."""
    k = S.shape[1]
    p11, p22 = S[P11].real, S[P22].real
    floor = power_floor * (p11.sum() + p22.sum()) / (2 * k) + np.finfo(np.float64).tiny
    H = np.zeros((4, k), dtype=np.complex128)
    valid = np.zeros(k, dtype=bool)
    for b in range(k):
        det = p11[b] * p22[b] - abs(S[P12, b]) ** 2
        if not (p11[b] > floor and p22[b] > floor and det >= det_threshold * p11[b] * p22[b]):
            continue
        P = np.array([[p11[b], S[P12, b]], [np.conj(S[P12, b]), p22[b]]])
        R = np.array([[S[P1Y1, b], S[P1Y2, b]], [S[P2Y1, b], S[P2Y2, b]]])
        h = np.linalg.solve(P, R)  # rows: input i, columns: output j
        H[:, b] = [h[0, 0], h[0, 1], h[1, 0], h[1, 1]]
        valid[b] = True
    return H, valid


def _c12_rows(ha: complex, hb: complex, hc: complex, wa: float, wb: float, wc: float) -> tuple[np.ndarray, np.ndarray]:
    """The corrected [C-12] for ``[λ, C]`` (module doc of dsp_service.modal): its matrix and right side."""
    wa2, wb2, wc2 = wa * wa, wb * wb, wc * wc
    dba, dca, dcb = hb - ha, hc - ha, hc - hb
    m = np.array(
        [
            [dba * dca * (wc2 - wb2), dba * (wc2 - wa2) - dca * (wb2 - wa2)],
            [dba * dcb * (wc2 - wa2), dba * (wc2 - wb2) - dcb * (wb2 - wa2)],
        ]
    )
    return m, np.array([m[0, 0] * wa2, m[1, 0] * wb2])


def c12_corrected(ha: complex, hb: complex, hc: complex, wa: float, wb: float, wc: float) -> tuple[complex, complex]:
    """``(λ, C)`` of one triplet from the corrected [C-12] by ``numpy.linalg.solve``."""
    m, r = _c12_rows(ha, hb, hc, wa, wb, wc)
    lam, c = np.linalg.solve(m, r)
    return complex(lam), complex(c)


def c12_printed(ha: complex, hb: complex, hc: complex, wa: float, wb: float, wc: float) -> tuple[complex, complex]:
    """[C-12] exactly as printed (its two columns swapped), solved for ``[λ; C]``: returns ``(C, λ)`` in truth."""
    m, r = _c12_rows(ha, hb, hc, wa, wb, wc)
    first, second = np.linalg.solve(m[:, ::-1], r)
    return complex(first), complex(second)


def parabola_vertex(mag: np.ndarray, k: int, r: int, limit: float | None = None) -> tuple[float, float]:
    """``(δ, ln peak)`` of the least-squares parabola (``numpy.polyfit``) through ``ln mag`` on bins
    ``k − r … k + r`` (``r`` clipped to the array), δ clipped to ±``limit`` (default ±r);
    ``(0, ln mag[k])`` when it is not concave. The three-point vertex (``r = 1``, ``limit = 0.5``) reads
    its peak as ``b − ¼(a − c)δ`` (``a, b, c`` the log magnitudes), the vertex formula, also where δ is clipped."""
    r = max(1, min(r, k, mag.size - 1 - k))
    j = np.arange(-r, r + 1)
    c2, c1, c0 = np.polyfit(j, np.log(mag[k - r : k + r + 1]), 2)
    if not c2 < 0.0:
        return 0.0, float(np.log(mag[k]))
    lim = float(r) if limit is None else limit
    d = min(lim, max(-lim, -0.5 * c1 / c2))
    if r == 1 and limit == 0.5:
        a, b, c = np.log(mag[k - 1 : k + 2])
        return d, float(b - 0.25 * (a - c) * d)
    return d, c0 + c1 * d + c2 * d * d


def half_power_crossings(mag: np.ndarray, freqs: np.ndarray, k: int, peak: float) -> tuple[float, float] | None:
    """The frequencies where ``mag`` falls below ``peak/√2`` nearest bin ``k`` on each side, interpolated
    linearly in power between the straddling bins (None without a crossing)."""
    half = peak * peak / 2.0
    p = mag * mag
    left = [i for i in range(k - 1, -1, -1) if p[i] < half]
    right = [i for i in range(k + 1, mag.size) if p[i] < half]
    if not left or not right:
        return None
    i0, i1 = left[0], right[0] - 1
    return float(np.interp(half, [p[i0], p[i0 + 1]], [freqs[i0], freqs[i0 + 1]])), float(np.interp(half, [p[i1 + 1], p[i1]], [freqs[i1 + 1], freqs[i1]]))


def zeta_from_half_power_width(bandwidth: float, peak_frequency: float) -> float:
    """ζ whose exact half-power width about the peak frequency [B.2] is ``bandwidth``: the root of
    ``ρ(ζ) = Δf/f_p`` by bisection on the closed-form half-power points."""
    rho = bandwidth / peak_frequency

    def width(z: float) -> float:
        root = 2.0 * z * np.sqrt(1.0 - z * z)
        return float((np.sqrt(1.0 - 2.0 * z * z + root) - np.sqrt(1.0 - 2.0 * z * z - root)) / np.sqrt(1.0 - 2.0 * z * z))

    lo, hi = 1e-9, float(np.sqrt((2.0 - np.sqrt(2.0)) / 4.0)) - 1e-12
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if width(mid) < rho else (lo, mid)
    return 0.5 * (lo + hi)
