"""The DSP's on-line transfer-function estimate recomputed off line from a run record (thesis §2.3, §4.1.1).

What the identifier does with the inputs ``u1``, ``u2`` and outputs ``y1``,
``y2`` it is sent, redone with SciPy only so that a download can be held
against an implementation nobody wrote for the rig:

* :func:`batch_ends`: the batches the controller sent, from the record's
  interrupt ticks;
* :func:`averaged_spectra`: the seven auto/cross spectra of the ``N`` samples
  ending at each batch (``scipy.signal.csd``/``welch``, one segment, periodic
  Hann, ``detrend='constant'``, density scaling), exponentially averaged as
  [2-9] with weight ``(1 − α)^(K−k)`` on snapshot ``k`` of ``K``;
* :func:`solve_2x2`: the 2×2 solve for H11..H22 (P21 = conj(P12);
  ``docs/identification-pitfalls.md``), nearly collinear bins solved along
  the dominant input direction as the DSP does;
* :func:`smooth` / :func:`named_tfs`: Savitzky–Golay across frequency of the
  real and imaginary parts, and H_tot as the mean of the four.
"""

from __future__ import annotations

import numpy as np
import scipy.signal as ss

PAIRS = ((0, 0), (0, 1), (0, 2), (0, 3), (1, 1), (1, 2), (1, 3))
"""Channel pairs (u1, u2, y1, y2 = 0..3) of P11, P12, P1y1, P1y2, P22, P2y1, P2y2."""
TF_NAMES = ("H11", "H12", "H21", "H22", "Htot")
"""The estimates a download carries, in the order :func:`named_tfs` returns them."""
COLLINEAR_DET = 1e-3
"""The DSP's det_threshold: below it a bin is solved along the dominant input direction (docs/identification.md)."""


def batch_ends(irq_applied: np.ndarray, batch_size: int, n_ticks: int) -> np.ndarray:
    """Last tick of every batch the controller sent.

    The first batch ends at tick ``batch_size − 1``; each next one goes when
    the previous interrupt is in and ``batch_size`` samples wait, i.e. ends at
    ``max(end + batch_size, tick of the previous interrupt)`` (the ticks where
    ``irq_applied`` > 0).
    """
    ends = [batch_size - 1]
    for tick in np.flatnonzero(np.asarray(irq_applied) > 0):
        nxt = max(ends[-1] + batch_size, int(tick))
        if nxt >= n_ticks:
            break
        ends.append(nxt)
    return np.asarray(ends, dtype=int)


def solve_2x2(s: np.ndarray) -> np.ndarray:
    """H11, H12, H21, H22 from the seven averaged spectra (rows as :data:`PAIRS`), P21 = conj(P12)."""
    p11, p12, p1y1, p1y2, p22, p2y1, p2y2 = s
    p21 = np.conj(p12)
    det = p11 * p22 - np.abs(p12) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.array(
            [
                (p1y1 * p22 - p12 * p2y1) / det,
                (p1y2 * p22 - p12 * p2y2) / det,
                (p2y1 * p11 - p21 * p1y1) / det,
                (p2y2 * p11 - p21 * p1y2) / det,
            ]
        )
        # collinear bins (normalised determinant below the DSP's 1e-3): the DSP solves them along the
        # dominant input direction, h_j = v (v^H r_j) / sigma_1; recomputed here with numpy's eigh
        pr = (p11 * p22).real
        col = np.flatnonzero((det.real < COLLINEAR_DET * pr) & ((p11 + p22).real > 0))
    if col.size:
        P = np.empty((col.size, 2, 2), dtype=complex)
        P[:, 0, 0], P[:, 0, 1], P[:, 1, 0], P[:, 1, 1] = p11[col], p12[col], p21[col], p22[col]
        w, V = np.linalg.eigh(P)
        v, sig = V[:, :, 1], w[:, 1]
        for j, (r1, r2) in enumerate(((p1y1, p2y1), (p1y2, p2y2))):
            c = (np.conj(v[:, 0]) * r1[col] + np.conj(v[:, 1]) * r2[col]) / sig
            h[j, col] = v[:, 0] * c  # H1j
            h[2 + j, col] = v[:, 1] * c  # H2j
    return h


def averaged_spectra(channels: np.ndarray, ends: np.ndarray, n: int, alpha: float, fs_hz: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Exponentially averaged ([2-9]) csd/welch spectra of ``channels`` (u1, u2, y1, y2) over the last ``n`` samples at each batch end.

    Only the batches with a full history (``end ≥ n − 1``) count. Returns the
    averaged spectra (7, n//2+1, rows as :data:`PAIRS`), the frequencies and
    the number of snapshots; ``ValueError`` when no batch has a full history.
    """
    use = ends[ends >= n - 1]
    if use.size == 0:
        raise ValueError("no batch with a full history")
    acc = None
    wsum = 0.0
    k_last = use.size - 1
    freqs = None
    for k, e in enumerate(use):
        seg = channels[:, e - n + 1 : e + 1]
        rows = []
        for a, b in PAIRS:
            if a == b:
                freqs, p = ss.welch(seg[a], fs=fs_hz, window="hann", nperseg=n, noverlap=0, detrend="constant", scaling="density")
                rows.append(p.astype(complex))
            else:
                freqs, p = ss.csd(seg[a], seg[b], fs=fs_hz, window="hann", nperseg=n, noverlap=0, detrend="constant", scaling="density")
                rows.append(p)
        w = (1.0 - alpha) ** (k_last - k)
        snap = w * np.array(rows)
        acc = snap if acc is None else acc + snap
        wsum += w
    assert acc is not None and freqs is not None
    return acc / wsum, freqs, int(use.size)


def smooth(h: np.ndarray, window: int, order: int) -> np.ndarray:
    """Savitzky–Golay across frequency (last axis) of the real and imaginary parts (``mode='interp'``)."""
    return ss.savgol_filter(h.real, window, order, axis=-1, mode="interp") + 1j * ss.savgol_filter(h.imag, window, order, axis=-1, mode="interp")


def named_tfs(spectra: np.ndarray, smoothing: tuple[int, int] | None = None) -> dict[str, np.ndarray]:
    """H11..H22 from the 2×2 solve of ``spectra`` (unsolved bins 0) and H_tot, their mean, keyed by :data:`TF_NAMES`.

    With ``smoothing`` = (window, order) the four are smoothed first, as the DSP downloads them.
    """
    h = np.nan_to_num(solve_2x2(spectra))
    if smoothing is not None:
        h = smooth(h, *smoothing)
    return {"H11": h[0], "H12": h[1], "H21": h[2], "H22": h[3], "Htot": h.mean(axis=0)}
