"""2-input, 2-output transfer-function solve (thesis [2-10 … 2-28], §5).

``H_ij`` is the transfer function from input ``i`` to output ``j``. With
``P_ij = E[U_i* U_j]``, ``P_iyj = E[U_i* Y_j]`` (``P21 = conj(P12)``), the
least-squares (H1) solution of ``Y_j = H_1j U_1 + H_2j U_2`` per bin is

* ``H1j = (P1yj P22 − P12 P2yj) / (P11 P22 − |P12|²)``   [2-21, 2-22]
* ``H2j = (P2yj P11 − P21 P1yj) / (P11 P22 − |P12|²)``   [2-23, 2-24] *corrected*:
  the thesis prints ``P12`` where ``P21`` belongs (tests/dsp/test_mimo_synthetic.py
  shows the printed form wrong).

Uncorrelated shortcut [2-25 … 2-28]: ``H_ij = P_iyj / P_ii`` (biased when
the inputs are correlated). ``H_tot`` = the unweighted mean of the four.

Validity (never NaN/inf): a bin is solved only if both input powers exceed a
floor (``power_floor`` × the mean input power over all bins and both
inputs, plus the smallest normal float) and, for the MIMO solve, the
normalised determinant ``(P11 P22 − |P12|²) / (P11 P22) = 1 − γ²₁₂`` (one
minus the inputs' coherence) is at least ``det_threshold``. Invalid bins are
set to exactly 0 and flagged in the mask. A single snapshot has ``γ² = 1``
at every bin, hence a zero determinant: everything is masked until the
averaged spectra hold independent data.

Collinear inputs (``collinear='dominant'``, the default of the identifier):
a bin whose normalised determinant is below ``det_threshold`` but whose
total input power clears the floor is not masked but solved in the
minimum-norm sense. With ``P = [[P11, P12], [P21, P22]]`` (Hermitian,
``P_ai = E[U_a* U_i]``) and ``r_j = [P1yj, P2yj]`` the normal equations are
``P h_j = r_j`` (``h_j = [H1j, H2j]``); the rank-1 pseudo-inverse keeps the
dominant eigenpair ``(σ₁, v)`` of ``P`` only::

    h_j = v (vᴴ r_j) / σ₁

which is what the data identify: the response along the dominant input
direction (for ``u2 = G u1``, ``v ∝ [1, conj G]`` and ``U1 H1j + U2 H2j``
is reproduced exactly), the per-input estimate ``H_1j = P1yj / P11`` when
input 1 dominates (``v → [1, 0]``), and the exact ``H_tot`` when the two
inputs move together (``v = [1, 1]/√2``). :attr:`MimoSolver.mode` says per
bin which solve was used: :data:`MODE_FULL`, :data:`MODE_DOMINANT` or
:data:`MODE_NONE` (masked: silent).

The module also holds the per-bin recursive least-squares estimators
(TTFE, [1-9, 1-10], [D.15–D.29]) selectable instead of spectral averaging.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from . import kernel
from .spectra import P1Y1, P1Y2, P2Y1, P2Y2, P11, P22

#: Row order of transfer-function arrays ``(4, K)``.
H11, H12, H21, H22 = range(4)
H_NAMES: tuple[str, ...] = ("11", "12", "21", "22")

_TINY = float(np.finfo(np.float64).tiny)

#: Per-bin solve used (:attr:`MimoSolver.mode`): masked, dominant direction (rank 1), full 2×2.
MODE_NONE, MODE_DOMINANT, MODE_FULL = 0, 1, 2


class MimoSolver:
    """Solves transfer functions from (averaged) spectra, on a bin slice, with preallocated buffers.

    ``solver='mimo'`` uses the corrected [2-21 … 2-24]; ``'uncorrelated'``
    the shortcut [2-25 … 2-28]. Spectra may be unnormalised (any common
    positive scale: the solve is a ratio). All outputs are full-length
    internal buffers of which only the requested slice is written; they are
    overwritten by the next call.
    """

    def __init__(
        self,
        n_bins: int,
        solver: str = "mimo",
        det_threshold: float = 1e-3,
        power_floor: float = 1e-12,
        collinear: str = "mask",
    ) -> None:
        if solver not in ("mimo", "uncorrelated"):
            raise ValueError(f"unknown solver {solver!r}")
        if collinear not in ("mask", "dominant"):
            raise ValueError(f"unknown collinear handling {collinear!r}")
        self.solver = solver
        self.collinear = collinear
        self.det_threshold = float(det_threshold)
        self.power_floor = float(power_floor)
        k = int(n_bins)
        self.n_bins = k
        self.H = np.zeros((4, k), dtype=np.complex128)
        self.source = np.zeros(k, dtype=np.complex128)
        self.valid = np.zeros(k, dtype=bool)
        self.mode = np.zeros(k, dtype=np.uint8)  #: per bin: MODE_NONE, MODE_DOMINANT or MODE_FULL
        self._b1 = np.empty(k, dtype=bool)
        self._inv = np.zeros(k)
        self._inv2 = np.zeros(k)
        self._c1 = np.empty(k, dtype=np.complex128)

    # ---------------------------------------------------------------- masks
    def _floor(self, S: NDArray[np.complex128]) -> float:
        """The input-power floor of the spectra ``S`` (:func:`.kernel.input_power_floor`)."""
        return float(kernel.input_power_floor(S, self.power_floor))

    def mask(self, S: NDArray[np.complex128], sl: slice = slice(None)) -> NDArray[np.bool_]:
        """Valid-bin mask on ``sl`` (a view into the full-length :attr:`valid`): the input powers, and
        for 'mimo' the normalised determinant (no dominant-direction solve).

        For 'uncorrelated' ``_inv = 1/P11`` and ``_inv2 = 1/P22`` on ``sl``, exactly 0 on invalid bins."""
        S = np.ascontiguousarray(S)
        floor = self._floor(S)
        if self.solver == "mimo":
            s0, s1, _ = sl.indices(self.n_bins)
            kernel.solve_full(S, s0, s1, floor, self.det_threshold, False, self.H, self.valid, self.mode)
            return self.valid[sl]
        p11, p22 = S[P11, sl].real, S[P22, sl].real
        valid = np.greater(p11, floor, out=self.valid[sl])
        valid &= np.greater(p22, floor, out=self._b1[sl])
        inv, inv2 = self._inv[sl], self._inv2[sl]
        inv.fill(0.0)
        inv2.fill(0.0)
        np.divide(1.0, p11, out=inv, where=valid)
        np.divide(1.0, p22, out=inv2, where=valid)
        return valid

    # --------------------------------------------------------------- solves
    def solve(self, S: NDArray[np.complex128], sl: slice = slice(None)) -> tuple[NDArray[np.complex128], NDArray[np.bool_]]:
        """All four transfer functions on ``sl``: ``(H[:, sl], valid[sl])`` (views); 'mimo' by the
        compiled solve (:func:`.kernel.solve_full`), which also sets :attr:`mode`."""
        S = np.ascontiguousarray(S)
        H = self.H[:, sl]
        if self.solver == "mimo":
            s0, s1, _ = sl.indices(self.n_bins)
            kernel.solve_full(S, s0, s1, self._floor(S), self.det_threshold, self.collinear == "dominant", self.H, self.valid, self.mode)
            return H, self.valid[sl]
        valid = self.mask(S, sl)
        np.multiply(S[P1Y1 : P1Y2 + 1, sl], self._inv[sl], out=H[H11 : H12 + 1])
        np.multiply(S[P2Y1:, sl], self._inv2[sl], out=H[H21:])
        np.multiply(valid, MODE_FULL, out=self.mode[sl], casting="unsafe")
        return H, valid

    def solve_source(self, S: NDArray[np.complex128], source: str = "tot", sl: slice = slice(None)) -> tuple[NDArray[np.complex128], NDArray[np.bool_]]:
        """Only the searched spectrum on ``sl``: one ``H_ij``, or the uncorrelated solve's ``H_tot``
        ``(A/P11 + B/P22)/4`` with ``A = P1y1 + P1y2``, ``B = P2y1 + P2y2`` (views). The corrected
        solve's ``H_tot`` is the compiled identification step's (:func:`.kernel.step_packed`)."""
        if source != "tot":
            H, valid = self.solve(S, sl)
            return H[H_NAMES.index(source)], valid
        if self.solver == "mimo":
            raise ValueError("the corrected H_tot is solved by the compiled step (dsp_service.kernel)")
        valid = self.mask(S, sl)
        out = self.source[sl]
        a = np.add(S[P1Y1, sl], S[P1Y2, sl], out=out)
        b = np.add(S[P2Y1, sl], S[P2Y2, sl], out=self._c1[sl])
        a *= self._inv[sl]
        b *= self._inv2[sl]
        a += b
        a *= 0.25
        return out, valid


# ---------------------------------------------------------------------------
# Per-bin recursive least squares (TTFE, [1-9, 1-10], [D.15–D.29])
# ---------------------------------------------------------------------------
def _initial_inverse_power(power: NDArray[np.float64], init_scale: float) -> NDArray[np.float64]:
    """Per-bin initial RLS inverse power ``init_scale / |x|²`` of the first snapshot.

    Scaling per bin keeps the regularisation ``λ^k / p_0`` the same *relative*
    size (``λ^k / init_scale``) at every bin, including weakly excited ones;
    bins with (near) zero power use the mean power instead.
    """
    mean = float(np.mean(power))
    floor = max(mean * 1e-12, float(np.finfo(np.float64).tiny))
    ref = np.where(power > floor, power, mean if mean > 0.0 else 1.0)
    return init_scale / ref


class ScalarRLS:
    """Four independent per-bin scalar RLS estimators ``H_ij`` from ``U_i`` to ``Y_j``.

    Complex form of [D.28, D.29] with forgetting factor ``λ`` (the thesis's
    ``α`` in D.28)::

        w_k = w_{k−1} + p_{k−1} x_k* (d_k − x_k w_{k−1}) / (λ + |x_k|² p_{k−1})
        p_k = p_{k−1} / (λ + |x_k|² p_{k−1})        (i.e. p_k⁻¹ = λ p_{k−1}⁻¹ + |x_k|²)

    (The restated D.29, ``p_k⁻¹ = p_{k−1}⁻¹ / (α + p_{k−1}⁻¹ x_k²)``, has its
    inverses misplaced; the line above is the exponentially weighted LS
    recursion.) The estimate is ``Σ λ^{k−i} x_i* d_i / (Σ λ^{k−i} |x_i|² + λ^k/p_0)``:
    the uncorrelated shortcut on exponentially averaged spectra with
    ``α = 1 − λ`` plus a vanishing regularisation ``λ^k / p_0``.

    ``p`` starts at ``p_0 = init_scale / |x_1|²`` per bin (first snapshot) and
    is clipped at ``p_0`` so a silent input cannot wind it up to overflow.
    """

    def __init__(self, n_bins: int, forgetting: float, init_scale: float = 1e8) -> None:
        if not 0.0 < forgetting <= 1.0:
            raise ValueError(f"forgetting factor must be in (0, 1], got {forgetting}")
        self.lam = float(forgetting)
        self.init_scale = float(init_scale)
        self.n_bins = int(n_bins)
        self.H = np.zeros((4, self.n_bins), dtype=np.complex128)
        self.p = np.zeros((2, self.n_bins))
        self.p0: NDArray[np.float64] | float = 0.0
        self.updates = 0

    def reset(self) -> None:
        self.H.fill(0.0)
        self.p.fill(0.0)
        self.p0 = 0.0
        self.updates = 0

    def update(self, X: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """One step with FFTs ``X`` (rows U1, U2, Y1, Y2); returns H (rows H11, H12, H21, H22)."""
        pw = X[0:2].real ** 2 + X[0:2].imag ** 2  # |U_i|², (2, K)
        if self.updates == 0:
            self.p0 = _initial_inverse_power(pw, self.init_scale)
            self.p[...] = self.p0
        self.updates += 1
        p = self.p
        den = self.lam + pw * p  # (2, K), > 0
        gain = p / den  # p_k, the new inverse "power"
        for i in range(2):
            x = X[i]
            for j in range(2):
                h = self.H[2 * i + j]
                err = X[2 + j] - x * h
                h += gain[i] * np.conj(x) * err
        np.minimum(gain, self.p0, out=p)
        return self.H


class VectorRLS:
    """Per-bin two-input RLS: ``Y_j = H_1j U_1 + H_2j U_2``, matrix form [D.15–D.27] per bin.

    With ``v = conj([U1, U2])`` and ``R_k = λ R_{k−1} + v vᴴ`` (so
    ``R_ab = Σ λ^{k−i} conj(U_a) U_b`` = exponentially weighted P_ab), the
    recursion tracks ``Q = R⁻¹`` (Hermitian 2×2, stored as q11, q12, q22)::

        g = Q v / (λ + vᴴ Q v),   h_j ← h_j + g (Y_j − uᵀ h_j),   Q ← (Q − g vᴴ Q) / λ

    Algebraically it equals the corrected MIMO solve on exponentially averaged
    spectra with ``α = 1 − λ`` (plus a vanishing ``λ^k Q_0⁻¹`` regularisation).
    ``Q`` is scaled down wherever its trace exceeds its initial value
    (anti-windup for a silent or collinear input; uniform scaling keeps it
    positive semi-definite).
    """

    def __init__(self, n_bins: int, forgetting: float, init_scale: float = 1e8) -> None:
        if not 0.0 < forgetting <= 1.0:
            raise ValueError(f"forgetting factor must be in (0, 1], got {forgetting}")
        self.lam = float(forgetting)
        self.init_scale = float(init_scale)
        self.n_bins = int(n_bins)
        self.H = np.zeros((4, self.n_bins), dtype=np.complex128)
        self.q11 = np.zeros(self.n_bins)
        self.q22 = np.zeros(self.n_bins)
        self.q12 = np.zeros(self.n_bins, dtype=np.complex128)
        self.q0: NDArray[np.float64] | float = 0.0
        self.updates = 0

    def reset(self) -> None:
        self.H.fill(0.0)
        self.q11.fill(0.0)
        self.q22.fill(0.0)
        self.q12.fill(0.0)
        self.q0 = 0.0
        self.updates = 0

    def update(self, X: NDArray[np.complex128]) -> NDArray[np.complex128]:
        """One step with FFTs ``X`` (rows U1, U2, Y1, Y2); returns H (rows H11, H12, H21, H22)."""
        u1, u2 = X[0], X[1]
        if self.updates == 0:
            pw = np.abs(u1) ** 2 + np.abs(u2) ** 2
            self.q0 = _initial_inverse_power(0.5 * pw, self.init_scale)
            self.q11[...] = self.q0
            self.q22[...] = self.q0
            self.q12.fill(0.0)
        self.updates += 1
        lam = self.lam
        v1, v2 = np.conj(u1), np.conj(u2)
        q11, q12, q22 = self.q11, self.q12, self.q22
        # Q v  (Q Hermitian: q21 = conj(q12))
        a1 = q11 * v1 + q12 * v2
        a2 = np.conj(q12) * v1 + q22 * v2
        # vᴴ Q v (real, ≥ 0)
        quad = (np.conj(v1) * a1 + np.conj(v2) * a2).real
        den = lam + quad
        g1 = a1 / den
        g2 = a2 / den
        H = self.H
        for j in range(2):
            err = X[2 + j] - u1 * H[j] - u2 * H[2 + j]  # rows: H1j at j, H2j at 2+j
            H[j] += g1 * err
            H[2 + j] += g2 * err
        # Q ← (Q − g (Qv)ᴴ) / λ   (vᴴ Q = (Q v)ᴴ)
        n11 = (q11 - (g1 * np.conj(a1)).real) / lam
        n22 = (q22 - (g2 * np.conj(a2)).real) / lam
        n12 = (q12 - g1 * np.conj(a2)) / lam
        # anti-windup: shrink Q uniformly (keeps it positive semi-definite)
        # wherever its trace exceeds the initial 2 q0
        shrink = np.minimum(1.0, 2.0 * self.q0 / np.maximum(n11 + n22, _TINY))
        np.multiply(n11, shrink, out=q11)
        np.multiply(n22, shrink, out=q22)
        np.multiply(n12, shrink, out=q12)
        return H
