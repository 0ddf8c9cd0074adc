"""Modal parameters from a transfer-function estimate: peaks, FWHM damping, VRM (§5, App. B, C).

Peak search
-----------
Global maximum of ``|H|`` over a search range, optionally weighted toward low
frequencies (to prefer the lower of two split poles, §5). The weight is a
power law, i.e. a straight line on the log–log (Bode) plot::

    w(f) = (f / f_lo) ** (−γ)      (a tilt of −20 γ dB/decade, γ = log_weight_exponent)

It only *ranks* candidate peaks; frequencies and magnitudes are refined on
the unweighted ``|H|``. Candidates are local maxima of the weighted
magnitude with a minimum prominence, as ``scipy.signal.find_peaks(…,
prominence=…)`` finds them on its dB values; up to ``max_peaks`` are kept,
best weighted magnitude first. The search is the compiled step's
(:func:`.kernel.step_packed`, tested against scipy).
Sub-bin refinement: a parabola through the log magnitudes of the three bins
around the maximum (vertex offset ``δ = ½(ln a − ln c)/(ln a − 2 ln b + ln c)``,
:func:`refine_peak`), or a least-squares parabola over more bins for noisy
raw estimates (:class:`PeakRefiner`).

FWHM damping (Appendix B)
-------------------------
For the displacement power spectrum ``P(r) = a / ((1 − r²)² + 4ζ² r²)``,
``r = ω/ω_n`` [B.2]: the peak is at ``r_p = √(1 − 2ζ²)`` (not ``r = 1``; the
thesis's B.3 slips here) with ``P(r_p) = a / (4ζ²(1 − ζ²))``; the half-power
points (``P = P(r_p)/2``, i.e. ``|H|/√2``) solve ``(1 − r²)² + 4ζ² r² =
8ζ²(1 − ζ²)``::

    r₁,₂² = 1 − 2ζ² ∓ 2ζ √(1 − ζ²)                  (real for ζ < 0.3827)

The measurable ratio is the width over the *peak* frequency,
``ρ = Δω/ω_p = (r₂ − r₁)/√(1 − 2ζ²)``, whence
``ρ² = 2 − 2√(1 − 8ζ² + 8ζ⁴)/(1 − 2ζ²)``, inverted exactly as::

    c = 1 − ρ²/2,      ζ² = ½ (1 − 1/√(2 − c²))

(:func:`zeta_from_fwhm_exact`). [B.1], ``ζ ≈ Δω/(2ω_n)``, overestimates ζ
by about ζ² when ω_n is the true natural frequency (+0.83 % at ζ = 0.09,
+1.04 % at ζ = 0.1, +4.7 % at 0.2) and by about 2ζ² when ω_n is taken as the
peak frequency as the thesis does (+2.1 % at ζ = 0.1). Half-power crossings
are interpolated linearly in power between bins.

Variable Residue Method (Appendix C, Lin, Lim & Liew 1995)
----------------------------------------------------------
Local model ``H(ω) = C / (λ − ω²) + D`` (one mode plus a constant residual
that may differ from triplet to triplet). Three bins a, b, c give, with
``Δba = H_b − H_a`` etc., after eliminating ``D`` and the quadratic term::

    [Δba Δca (ωc² − ωb²),   Δba(ωc² − ωa²) − Δca(ωb² − ωa²)] [λ]   [Δca Δba ωa² (ωc² − ωb²)]
    [Δba Δcb (ωc² − ωa²),   Δba(ωc² − ωb²) − Δcb(ωb² − ωa²)] [C] = [Δcb Δba ωb² (ωc² − ωa²)]

The matrix printed as [C-12] has these two *columns swapped*: solved as
printed for ``[λ; C]`` its first unknown is in fact the modal constant C
(checked on a synthetic single-mode FRF: the printed reading returns
"ω_r" = √C). Read as ``[C; λ]`` it is correct.

[C-13, C-14] give ``ω_r = √(Re λ)``, ``η = Im λ / ω_r²`` (hysteretic
damping, ζ ≈ η/2), exact for ``C/(ω_r²(1 + iη) − ω²)``. For the viscous modes of
the plant model, ``1/(ω_n² − ω² + 2iζω_nω)``, linearising ``ω`` in ``ω²`` at
resonance gives ``λ ≈ ω_n² (1 + iζ)²/(1 + ζ²)``, hence the *viscous*
reading used by default: ``ω_n = √|λ|``, ``ζ = tan(arg λ / 2)``
(residual bias +0.12 % at ζ = 0.05, +0.4 % at 0.09; the hysteretic reading
is −ζ² low in frequency and +1.5ζ²… high in damping).

Robustness (:class:`VrmEstimator`): triplets are taken from up to 11 points
spread over ``±1.5`` half-power half-widths around the peak, keeping those
whose outer points are at least half the band apart (adjacent-bin triplets
are dominated by noise: in a Monte-Carlo at 3 % complex noise their ζ error
is 4–10× larger); non-physical triplets (``Re λ ≤ 0``, ``ζ ∉ (0,
zeta_max]``) are discarded and the λ of the rest averaged with weights
``|den_t|``; the averaged mode must lie within two bins of the band. :func:`vrm_lambdas`
solves for λ alone (C eliminated; the tests hold it to the full corrected 2×2
system solved by ``numpy.linalg.solve``).
"""

from __future__ import annotations

import math
from itertools import combinations
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dsp_service import kernel
from dsp_service.ratfit import denominator_lstsq

_TINY = float(np.finfo(np.float64).tiny)
#: Largest ζ with two half-power points: 1 − 2ζ² = 2ζ√(1 − ζ²) ⇔ ζ² = (2 − √2)/4.
ZETA_MAX_HALF_POWER = math.sqrt((2.0 - math.sqrt(2.0)) / 4.0)


# ---------------------------------------------------------------------------
# Peak search
# ---------------------------------------------------------------------------
def log_weights(freqs: NDArray[np.float64], f_ref: float, exponent: float) -> NDArray[np.float64]:
    """Low-frequency weight ``(f / f_ref) ** (−exponent)`` (1 where ``f ≤ 0``)."""
    f = np.asarray(freqs, dtype=np.float64)
    w = (np.maximum(f, _TINY) / f_ref) ** (-exponent)
    w[f <= 0.0] = 1.0
    return w


def refine_peak(mag: NDArray[np.float64], k: int) -> tuple[float, float]:
    """Parabolic vertex on ``ln |H|`` around bin ``k`` of a magnitude array: ``(δ, ln peak)``
    (the identification step's own, :mod:`.kernel`)."""
    d, lv = kernel._refine_peak(np.ascontiguousarray(mag, dtype=np.float64), int(k))
    return float(d), float(lv)


def parabola_fit_rows(r: int) -> NDArray[np.float64]:
    """The least-squares parabola ``c0 + c1 j + c2 j²`` on ``j = −r … r`` as a ``(3, 2r + 1)``
    matrix (the pseudo-inverse of ``[1, j, j²]``), in closed form.

    On the symmetric grid the normal equations split: ``c1 = Σ j y / S2`` and
    ``[c0, c2]`` from ``[[n, S2], [S2, S4]]`` (``S2 = Σ j²``, ``S4 = Σ j⁴``,
    integers), so each weight is one integer over another, rounded once. An
    SVD (``numpy.linalg.pinv``, which this replaced) rounds as the host's
    LAPACK kernel does, and its last bit reached the identified magnitudes."""
    j = np.arange(-r, r + 1, dtype=np.int64)
    n = 2 * r + 1
    s2 = int(np.sum(j * j))
    s4 = int(np.sum(j**4))
    det = n * s4 - s2 * s2
    jj = j * j
    return np.vstack([(s4 - s2 * jj) / det, j / s2, (n * jj - s2) / det]).astype(np.float64)


class PeakRefiner:
    """Least-squares parabola on ``ln |H|`` over ``±r`` bins around a peak bin (precomputed fits).

    With ``r = 1`` it is the classic three-point vertex; wider fits
    (the identifier uses ``r ≈`` half the half-power half-width) average the
    noise of a raw estimate down: in a Monte-Carlo at 3 % complex noise the
    90th-percentile frequency error fell from 0.76 to 0.37 bins for a
    ζ = 0.05 mode at 9 Hz. ``pinv[r, :, : 2r + 1]`` holds the fit of half-width ``r``
    (:func:`parabola_fit_rows`), as the identification step reads it.
    """

    def __init__(self, r_max: int = 8) -> None:
        self.r_max = int(r_max)
        self.pinv = np.zeros((self.r_max + 1, 3, 2 * self.r_max + 1))
        for r in range(1, self.r_max + 1):
            self.pinv[r, :, : 2 * r + 1] = parabola_fit_rows(r)


# ---------------------------------------------------------------------------
# FWHM, Appendix B
# ---------------------------------------------------------------------------
def half_power_points(zeta: float) -> tuple[float, float]:
    """Exact half-power frequency ratios ``(r₁, r₂)`` of ``P(r)`` [B.2] (derived, see module doc)."""
    z2 = zeta * zeta
    root = 2.0 * zeta * math.sqrt(1.0 - z2)
    lo2 = 1.0 - 2.0 * z2 - root
    if lo2 <= 0.0:
        raise ValueError(f"no lower half-power point for zeta={zeta} (needs zeta < 0.3827)")
    return math.sqrt(lo2), math.sqrt(1.0 - 2.0 * z2 + root)


def fwhm_ratio(zeta: float) -> float:
    """``ρ = Δω / ω_peak`` of the exact ``P(r)`` for damping ``zeta``."""
    r1, r2 = half_power_points(zeta)
    return (r2 - r1) / math.sqrt(1.0 - 2.0 * zeta * zeta)


def zeta_fwhm_approx(bandwidth_hz: float, natural_frequency_hz: float) -> float:
    """[B.1]: ``ζ ≈ Δω / (2 ω_n)``."""
    return bandwidth_hz / (2.0 * natural_frequency_hz)


def zeta_from_fwhm_exact(bandwidth_hz: float, peak_frequency_hz: float) -> float:
    """Exact inversion of the half-power width measured about the *peak* frequency.

    ``ρ = Δf/f_p``, ``c = 1 − ρ²/2``, ``ζ² = ½(1 − 1/√(2 − c²))`` (module doc).
    Valid for ``ρ`` up to ``√2`` (ζ → 0.3827, :data:`ZETA_MAX_HALF_POWER`, returned beyond).
    The identification step's own (:mod:`.kernel`).
    """
    return float(kernel._zeta_fwhm(float(bandwidth_hz), float(peak_frequency_hz), True))


def half_power_bandwidth(
    mag: NDArray[np.float64],
    freqs: NDArray[np.float64],
    k: int,
    peak_mag: float,
    valid: NDArray[np.bool_] | None = None,
    max_bins: int = 64,
) -> tuple[float, float] | None:
    """Frequencies ``(f_left, f_right)`` where ``|H| = peak_mag/√2`` (half power) nearest bin ``k``.

    Looks at most ``max_bins`` bins each side; the crossings are
    interpolated linearly in power (``|H|²``) between the two straddling
    bins. ``None`` if a side does not drop below half power in reach, or a
    straddling bin is masked (``valid`` False). The identification step's own (:mod:`.kernel`).
    """
    m = np.ascontiguousarray(mag, dtype=np.float64)
    f0, f1 = freqs[0:2].tolist()
    vd = np.ones(m.size, dtype=np.bool_) if valid is None else np.ascontiguousarray(valid, dtype=np.bool_)
    ok, fl, fr = kernel._half_power(m, f0, f1 - f0, int(k), float(peak_mag), vd, valid is not None, int(max_bins))
    return (float(fl), float(fr)) if ok else None


# ---------------------------------------------------------------------------
# Variable Residue Method, Appendix C
# ---------------------------------------------------------------------------
def vrm_lambdas(
    ha: NDArray[np.complex128],
    hb: NDArray[np.complex128],
    hc: NDArray[np.complex128],
    fa: NDArray[np.float64],
    fb: NDArray[np.float64],
    fc: NDArray[np.float64],
) -> tuple[NDArray[np.complex128], NDArray[np.float64]]:
    """``(λ, weight)`` of every triplet ``(a, b, c)`` of H values at frequencies ``f`` (any unit:
    λ comes in its square): the corrected [C-12] with C eliminated, which leaves one linear equation::

        λ [Δba(fc² − fa²) − Δca(fb² − fa²)] = Δba fb² (fc² − fa²) − Δca fc² (fb² − fa²)

    and its coefficient's magnitude as the weight (0: a singular triplet, whose λ is not
    finite). The identification step's own (:mod:`.kernel`)."""
    ha, hb, hc = (np.asarray(h, dtype=np.complex128) for h in (ha, hb, hc))
    g = np.empty((12, ha.size))
    for row, f in enumerate((fa, fb, fc)):
        g[row] = np.square(np.asarray(f, dtype=np.float64))
    for row, h in zip((3, 5, 7), (ha, hb, hc)):
        g[row], g[row + 1] = h.real, h.imag
    kernel._vrm_lambdas(g)
    lam: NDArray[np.complex128] = g[9] + 1j * g[10]
    return lam, g[11].copy()


def vrm_modal(
    lam: NDArray[np.complex128] | complex,
    model: Literal["viscous", "hysteretic"] = "viscous",
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(f_n, ζ)`` from the eigenvalues λ (:func:`.kernel.vrm_reading`; ``f_n`` in the unit whose
    square λ is in): ``'hysteretic'``: [C-13, C-14], ``f_n = √Re λ``, ``ζ = η/2 = Im λ / (2 Re λ)``;
    ``'viscous'`` (default): ``f_n = √|λ|``, ``ζ = tan(arg λ / 2)``. Non-physical λ
    (``Re λ ≤ 0``) give ``(0, 0)``."""
    if model not in ("viscous", "hysteretic"):
        raise ValueError(f"unknown damping model {model!r}")
    flat = np.asarray(lam, dtype=np.complex128).ravel()
    out = np.array([kernel.vrm_reading(float(z.real), float(z.imag), model == "viscous") for z in flat.tolist()]).reshape(-1, 2)
    shape = np.shape(lam)
    return out[:, 0].reshape(shape), out[:, 1].reshape(shape)


class VrmEstimator:
    """Robust VRM over bin triplets of a band around a peak (Appendix C).

    The band is ``±h`` bins around the peak with ``h = band_factor ×`` the
    half-power half-width (from FWHM, or a default), at least 1 bin. To bound
    the cost, at most ``2 m_max + 1`` points are used: ``m = min(h, m_max)``
    points each side with a stride ``s = round(h/m)`` bins. Every triplet of
    those points whose outer points are at least ``m`` points apart is solved
    (:func:`vrm_lambdas`; wide triplets resist noise far better than
    adjacent bins, whose differences are noise-dominated). Non-physical
    triplets are discarded (``Re λ ≤ 0``, ``ζ ∉ (0, zeta_max]``, a singular
    system); the rest are averaged with weights
    ``|den_t|`` (the magnitude of the triplet's λ coefficient, small when
    the triplet's differences are small and noise-dominated); ``f_n`` and ``ζ``
    come from the averaged λ, which must lie within two bins of the band.
    (Weighted mean and median were compared in a
    Monte-Carlo at 3–12 % complex noise: the weighted mean was as good or
    slightly better, and cheaper.) The identification step runs it compiled
    (:func:`.kernel._vrm`) on the tables built here (``tri``, ``n_tri``).
    """

    def __init__(
        self,
        m_max: int = 5,
        band_factor: float = 1.5,
        zeta_max: float = 0.5,
        model: Literal["viscous", "hysteretic"] = "viscous",
    ) -> None:
        if m_max < 1:
            raise ValueError("m_max must be >= 1")
        if model not in ("viscous", "hysteretic"):
            raise ValueError(f"unknown damping model {model!r}")
        self.m_max = int(m_max)
        self.band_factor = float(band_factor)
        self.zeta_max = float(zeta_max)
        self.model = model
        zm = self.zeta_max
        # physical: 0 < Im λ ≤ c·Re λ with c = tan(2 atan ζmax) (viscous, ζ = tan(arg λ / 2)) or 2 ζmax (hysteretic)
        self._im_over_re_max = math.tan(2.0 * math.atan(zm)) if model == "viscous" and zm < 1.0 else (2.0 * zm if model == "hysteretic" else math.inf)
        # per m: the triplets (a, b, c) of the 2m + 1 points, as offsets −m … m in strides (tri[m, : n_tri[m]])
        triplets = [np.zeros((0, 3), dtype=np.intp)]
        for m in range(1, self.m_max + 1):
            tri = [c for c in combinations(range(2 * m + 1), 3) if c[2] - c[0] >= max(m, 2)]
            triplets.append(np.array(tri, dtype=np.intp).reshape(-1, 3) - m)
        self.n_tri = np.array([t.shape[0] for t in triplets], dtype=np.intp)
        self.tri = np.zeros((len(triplets), max(1, int(self.n_tri.max())), 3), dtype=np.intp)
        for m, t in enumerate(triplets):
            self.tri[m, : t.shape[0]] = t

    def estimate(
        self,
        H: NDArray[np.complex128],
        freqs: NDArray[np.float64],
        k: int,
        half_width_bins: float,
        valid: NDArray[np.bool_] | None = None,
    ) -> tuple[float, float, int] | None:
        """``(f_n [Hz], ζ, triplets used)`` around bin ``k`` of ``H``, or ``None``.

        ``half_width_bins`` is the half-power half-width; ``valid`` the bin
        mask (masked bins are never used; the band shrinks to avoid them and
        the array's ends). Works in Hz² (λ's units cancel in ζ).
        """
        hd = np.ascontiguousarray(H, dtype=np.complex128)
        fd = np.ascontiguousarray(freqs, dtype=np.float64)
        vd = np.ones(hd.size, dtype=np.bool_) if valid is None else np.ascontiguousarray(valid, dtype=np.bool_)
        args = (self.m_max, self.band_factor, self.zeta_max, self._im_over_re_max, self.model == "viscous", self.tri, self.n_tri)
        ok, fn, zeta, used = kernel._vrm(hd, fd, vd, valid is not None, int(k), float(half_width_bins), *args)
        return (float(fn), float(zeta), int(used)) if ok else None


def fit_mode_transient(
    freqs_hz: NDArray[np.float64],
    inputs: NDArray[np.complex128],
    outputs: NDArray[np.complex128],
    iterations: int = 4,
    numerator_order: int = 2,
    transient_order: int = 2,
) -> tuple[float, float] | None:
    """``(f_n Hz, ζ)`` of the mode in a band, fitted to the DFTs of *one* record, transient included.

    Why: on the rig the first mode is not driven by a stationary input but
    rung by the trajectory's corners, and the inputs carry little power at the
    mode (three decades below 1 Hz). The output of a finite record then holds
    the free decay of excitations before the record began (and the record's
    own end cut off): a term no spectral average of ``U* Y / U* U`` removes,
    which at the mode dominates the input-driven part and narrows the peak
    (ζ 0.005–0.06 read for a true 0.09, also on noiseless data of the linear
    model at a fixed configuration). For a rectangular-window DFT of a record
    of a linear system that term is exact and rational with the system's own
    poles (Pintelon & Schoukens, *System Identification: A Frequency Domain
    Approach*, the transient term ``T(Ω) = I(Ω)/A(Ω)``)::

        Y_j(k) = Σ_i B_ij(s_k)/A(s_k) · U_i(k) + T_j(s_k)/A(s_k)

    Locally around one mode, ``A = s̃² + a₁ s̃ + a₀`` (``s̃ = s/ω_c``, ``ω_c``
    the band's centre, for conditioning), ``B_ij`` real polynomials of degree
    ``numerator_order``, ``T_j`` complex of degree ``transient_order`` (it also
    absorbs the other modes' slow variation over the band). ``A Y − Σ B U − T = 0``
    is linear in the unknowns (Levy); ``iterations`` Sanathanan–Koerner passes
    re-weight by ``1/|A_prev|``. The outputs share ``A``. Bounded cost:
    ``iterations`` least-squares solves of ``4B × (2 + m(n_i(n_b+1) + 2(n_t+1)))``.

    ``inputs`` ``(n_i, B)``, ``outputs`` ``(m, B)``: DFT values at ``freqs_hz`` ``(B,)``
    of the mean-removed, unwindowed record. None if the fit is unphysical.
    """
    f = np.asarray(freqs_hz, dtype=np.float64)
    U = np.atleast_2d(np.asarray(inputs, dtype=np.complex128))
    Y = np.atleast_2d(np.asarray(outputs, dtype=np.complex128))
    ni, b = U.shape
    m = Y.shape[0]
    n_par = 2 + m * (ni * (numerator_order + 1) + 2 * (transient_order + 1))
    if b < 2 or 2 * m * b < n_par or Y.shape[1] != b or f.size != b:
        return None
    if not (np.all(np.isfinite(U)) and np.all(np.isfinite(Y))):
        return None
    wc = 2.0 * math.pi * float(np.mean(f))
    if not wc > 0.0:
        return None
    s: NDArray[np.complex128] = (2j * math.pi * f / wc).astype(np.complex128)
    A, rhs = _transient_levy_rows(s, U, Y, numerator_order + 1, transient_order + 1)
    a1 = a0 = 0.0
    w = np.ones(b)
    for it in range(max(1, iterations)):
        if it:
            w = 1.0 / np.maximum(np.abs(s * s + a1 * s + a0), 1e-12)
        Aw = (A * w[None, :, None]).reshape(m * b, n_par)
        rw = (rhs * w[None, :]).reshape(m * b)
        M = np.vstack([Aw.real, Aw.imag])
        r = np.concatenate([rw.real, rw.imag])
        den = denominator_lstsq(M, r)
        if den is None:
            return None
        a1, a0 = den
    wn = math.sqrt(a0)
    zeta = a1 / (2.0 * wn)
    if not 0.0 < zeta < 1.0:
        return None
    return wn * wc / (2.0 * math.pi), zeta


def _transient_levy_rows(
    s: NDArray[np.complex128], U: NDArray[np.complex128], Y: NDArray[np.complex128], nb1: int, nt1: int
) -> tuple[NDArray[np.complex128], NDArray[np.complex128]]:
    """The unweighted Levy rows ``A θ = rhs`` of :func:`fit_mode_transient` per output ``(m, B, n_par)``:
    ``θ = [a₁, a₀, then per output the real B_ij coefficients (nb1 each) and T_j's (re, im; nt1 each)]``,
    ``rhs = −Y s̃²``."""
    ni, b = U.shape
    m = Y.shape[0]
    per_out = ni * nb1 + 2 * nt1  # B coefficients (real), T coefficients (re, im)
    pw = np.stack([s**p for p in range(max(nb1, nt1))])  # (p, B)
    A = np.zeros((m, b, 2 + m * per_out), dtype=np.complex128)
    rhs = np.empty((m, b), dtype=np.complex128)
    for j in range(m):
        A[j, :, 0] = Y[j] * s
        A[j, :, 1] = Y[j]
        rhs[j] = -Y[j] * s * s
        col = 2 + j * per_out
        for i in range(ni):
            A[j, :, col : col + nb1] = -(U[i][None, :] * pw[:nb1]).T
            col += nb1
        A[j, :, col : col + nt1] = -pw[:nt1].T
        A[j, :, col + nt1 : col + 2 * nt1] = -1j * pw[:nt1].T
    return A, rhs
