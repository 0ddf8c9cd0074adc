"""A fast recursive parametric identifier: 2-input 2-output ARX with a common denominator, in QR form.

The thesis chose the ETFE because an iterative estimator's compute could not
be bounded per batch (§2.2, §5.3). This one keeps that promise: one batch of
``l`` samples costs ``2l + p`` Givens row updates of the ``(p + 1) × (p + 1)``
triangular factor (``p`` parameters), whatever the data.

Model (equation error, shared denominator: the modes are the plant's, common to
all four transfer functions)::

    A(q) y_j(t) = B_1j(q) u_1(t) + B_2j(q) u_2(t) + e_j(t),   j = 1, 2
    A(q) = 1 + a_1 q⁻¹ + … + a_na q⁻ⁿᵃ,   B_ij(q) = b_ij,1 q⁻¹ + … + b_ij,nb q⁻ⁿᵇ

so ``θ = [a, b_11, b_21, b_12, b_22]`` (``p = na + 4 nb``) and every sample
gives two regression rows (one per output) sharing ``a``.

Recursion (square-root information filter with exponential forgetting
``λ`` per sample): the upper-triangular ``R`` of the weighted, augmented data
matrix ``[Φ | y]`` is updated by one QR of

    [ λ^(l/2) R                           ]
    [ λ^((l−1−s)/2) [φ_s | y_s], s < l     ]
    [ (δ (1 − λ^l))^(1/2) [I_p | 0]        ]

The last block keeps a constant ridge ``δ`` (the information never decays
below ``δ I``: a silent or collinear input cannot make ``R`` singular).
Orthogonal transformations only, no covariance matrix propagated: the
round-off of plain RLS's ``P`` update (which loses symmetry and positive
definiteness over ~10⁵ iterations, as the thesis warns) cannot build up;
``θ`` is a back-substitution on ``R``. The result equals the batch
exponentially weighted ridge least squares (tested against ``numpy.linalg.lstsq``).
The rotations, the back-substitution and the a-priori errors run in
:mod:`dsp_service.arx_kernel`, in one defined order: the same bits on every host.

Before the regression every channel goes through the same band-pass
(``scipy.signal`` Butterworth, state carried across batches): the same LTI
filter on inputs and outputs leaves ``B/A`` unchanged and concentrates the
equation error in the band of the modes (the trajectory's slow motion
would otherwise dominate). Channels are divided by scales fixed from the
first batch with signal (the ridge is then relative).

Poles: the roots ``z_k`` of ``A``, ``s_k = f_s ln z_k``, ``f_n = |s|/2π``,
``ζ = −Re s/|s|``; kept when in the search band, stable, with
``0 < ζ < max_damping``. A pole's strength is its modal peak in the four
transfer functions, ``√(Σ_ij |r_ij,k|²) / (1 − |z_k|)`` with ``r_ij,k`` the
residue of ``B_ij/A`` at ``z_k``; poles weaker than ``min_relative_strength``
of the strongest are dropped (the extra poles of an over-parametrised ``A``
model noise, not modes).

Regime bank (``regime_bank`` > 0, off by default) and the change detector
(``change_detection``): :mod:`.arx_regime_bank`, :mod:`.arx_change`.
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import scipy.signal
from numpy.typing import NDArray

from dsp_service import arx_kernel
from dsp_service.arx_change import ChangeDetector
from dsp_service.arx_config import ArxConfig
from dsp_service.arx_kernel import absorb_rows, back_substitute, equation_errors
from dsp_service.arx_poles import ArxPole, modal_poles
from dsp_service.arx_regime_bank import Regime, RegimeBank, RegimeBankState, check_bank_state


class RecursiveArx:
    """Pure, synchronous recursive ARX identifier (see module doc). One :meth:`update` per batch."""

    def __init__(self, cfg: ArxConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else ArxConfig()
        c = self.cfg
        self._sos = scipy.signal.butter(c.prefilter_order, c.band_hz, btype="bandpass", fs=c.sample_rate_hz, output="sos")
        self._lag = max(c.na, c.nb)
        arx_kernel.warm_up()  # compiled (or loaded from numba's cache) before the first batch
        self.reset()

    def reset(self) -> None:
        c = self.cfg
        p = c.n_params
        self.R = np.zeros((p + 1, p + 1))
        self.R[:p, :p] = math.sqrt(c.ridge) * np.eye(p)
        self.theta = np.zeros(p)
        self._zi = np.zeros((self._sos.shape[0], 4, 2))
        self._tail = np.zeros((4, self._lag))  # last filtered samples (u1, u2, y1, y2)
        self._tail_bp = np.zeros((4, self._lag))  # the same before the 1/Â prefilter
        self._scale: NDArray[np.float64] | None = None
        self.samples = 0  #: samples regressed since the reset
        self._skip = 0  #: model samples still to filter without regressing (after a gap)
        self._phase = 0  #: raw samples filtered so far, modulo the decimation
        self._sm_a = np.zeros(c.na + 1)  #: the Steiglitz–McBride prefilter's denominator (starts as 1)
        self._sm_a[0] = 1.0
        self._sm_zi = np.zeros((4, c.na))
        self.residual_power = 0.0  #: weighted mean squared one-step equation error (scaled units)
        self._weight_sum = 0.0
        self._change = ChangeDetector(c)
        self._bank = RegimeBank(c)
        self._frozen = 0  #: model samples the live model is still held unchanged after a switch

    @property
    def changes_detected(self) -> int:
        """Alarms of the change detector since the reset (each discounted the model)."""
        return self._change.detected

    @property
    def bank(self) -> list[Regime]:
        """The remembered regimes (at most ``regime_bank``, :mod:`.arx_regime_bank`)."""
        return self._bank.regimes

    @property
    def bank_switches(self) -> int:
        """Switches to a remembered regime since the reset."""
        return self._bank.switches

    # ------------------------------------------------------------------ data
    def update(self, inputs: NDArray[np.float64], outputs: NDArray[np.float64]) -> NDArray[np.float64]:
        """Regress one batch (``inputs``, ``outputs`` each ``(2, l)``); returns θ."""
        x = np.vstack([np.asarray(inputs, dtype=np.float64), np.asarray(outputs, dtype=np.float64)])
        n = x.shape[1]
        if n == 0:
            return self.theta
        xf, self._zi = scipy.signal.sosfilt(self._sos, x, axis=-1, zi=self._zi)
        if self._scale is None:
            rms = np.sqrt(np.mean(xf * xf, axis=1))
            if not np.all(rms > 0):  # a silent channel: no scale yet; keep the (decimated) samples as the regressors' past
                dec = self._decimate(xf)
                self._tail = np.hstack([self._tail, dec])[:, -self._lag :]
                self._tail_bp = np.hstack([self._tail_bp, dec])[:, -self._lag :]
                return self.theta
            self._scale = 1.0 / rms
            self._tail *= self._scale[:, None]  # the past kept from silent batches, in the same scaled units
            self._tail_bp *= self._scale[:, None]
        xf = xf * self._scale[:, None]
        xf = self._decimate(xf)
        n = xf.shape[1]
        if n == 0:
            return self.theta
        ext_bp = np.hstack([self._tail_bp, xf])  # the band-passed channels before 1/Â (the regime bank compares on them)
        self._tail_bp = ext_bp[:, -self._lag :].copy()
        if self.cfg.steiglitz_mcbride:
            xf = self._sm_filter(xf)
        ext = np.hstack([self._tail, xf])  # (4, lag + n)
        self._tail = ext[:, -self._lag :].copy()
        if self._skip:
            drop = min(self._skip, n)
            self._skip -= drop
            ext, ext_bp, n = ext[:, drop:], ext_bp[:, drop:], n - drop
            if n == 0:
                return self.theta
        c = self.cfg
        p = c.n_params
        rows = self._rows(ext, n)
        ready = self.samples >= c.memory_samples and self.residual_power > 0
        e: NDArray[np.float64] | None = None
        if ready:  # a-priori equation errors, both outputs
            e = np.empty(2 * n)
            equation_errors(rows, self.theta, e)
        if c.change_detection and e is not None and self._change.update(e, n, self.residual_power):
            self.discount(c.change_discount)
        if c.regime_bank and e is not None and self._bank_step(ext_bp, n):
            self._frozen = int(round(c.bank_hold_s * c.model_rate_hz))
        if self._frozen > 0:
            # just after a switch the batches hold the change's own transient (the payload's kick and load step through
            # the band-pass), which no model of the class explains: the remembered model is kept as it is meanwhile
            self._frozen -= n
            self.samples += n
            return self.theta
        if c.huber_k > 0 and e is not None:
            # bounded influence (Huber): σ is the model's weighted residual rms; an impulsive disturbance the inputs do
            # not explain (the payload released or picked up kicks the links) enters with at most k·σ per sample
            lim = c.huber_k * math.sqrt(self.residual_power)
            rows *= np.minimum(1.0, lim / np.maximum(np.abs(e), 1e-300))[:, None]
        lam = c.forgetting
        w = np.sqrt(lam ** (n - 1 - np.arange(n, dtype=np.float64)))
        rows[:n] *= w[:, None]
        rows[n:] *= w[:, None]
        decay = lam**n
        self._absorb(decay, rows)
        self.samples += n  # model samples (at fs / D)
        self._weight_sum = decay * self._weight_sum + float(np.sum(w * w))
        self.residual_power = float(self.R[p, p] ** 2) / (2.0 * max(self._weight_sum, 1e-300))
        return self.theta

    def _rows(self, ext: NDArray[np.float64], n: int) -> NDArray[np.float64]:
        """The batch's ``2n × (p + 1)`` regression rows ``[φ | y]`` from ``ext`` (``(4, lag + n)``: u1, u2, y1, y2)."""
        c = self.cfg
        na, nb, lag, p = c.na, c.nb, self._lag, c.n_params
        # regressors: row t of output j: [−y_j(t−1..t−na), (u1, u2)(t−1..t−nb) in block j]
        t = lag + np.arange(n)
        ky = t[:, None] - 1 - np.arange(na)[None, :]
        ku = t[:, None] - 1 - np.arange(nb)[None, :]
        U = np.hstack([ext[0][ku], ext[1][ku]])  # (n, 2 nb)
        rows = np.zeros((2 * n, p + 1))
        rows[:n, :na] = -ext[2][ky]
        rows[n:, :na] = -ext[3][ky]
        rows[:n, na : na + 2 * nb] = U
        rows[n:, na + 2 * nb : p] = U
        rows[:n, p] = ext[2][t]
        rows[n:, p] = ext[3][t]
        return rows

    # ---------------------------------------------------------------- the regime bank
    def _bank_step(self, ext_bp: NDArray[np.float64], n: int) -> bool:
        """One batch of the regime bank (:meth:`.arx_regime_bank.RegimeBank.step`); True when the live model
        became a remembered one. Compared on the band-passed rows before the live model's 1/Â: with the live
        prefilter the rows favour the live model (after the release at 62 s in id-lag the remembered model
        then looked worse for ~1 s)."""
        rb = self._rows(ext_bp, n)
        eb = np.empty(2 * n)
        equation_errors(rb, self.theta, eb)
        snapshot = lambda: Regime(self.R.copy(), self.theta.copy(), self.residual_power, self._weight_sum, 0)  # noqa: E731
        reg = self._bank.step(rb, eb, n, self.theta, self._signature, snapshot)
        if reg is None:
            return False
        self.R = reg.R.copy()
        self.theta = reg.theta.copy()
        self.residual_power = reg.residual_power
        self._weight_sum = reg.weight_sum
        return True

    def _signature(self, theta: NDArray[np.float64]) -> NDArray[np.float64]:
        """The frequencies (Hz) of the first ``bank_signature_poles`` modal poles of the model ``theta`` (NaN-padded)."""
        live = self.theta
        self.theta = theta
        try:
            f = [p.frequency_hz for p in self.poles()]
        finally:
            self.theta = live
        k = self.cfg.bank_signature_poles
        return np.array((f + [math.nan] * k)[:k])

    def bank_state(self) -> RegimeBankState:
        """The bank as it stands, to seed another model (:meth:`load_bank`); ``ValueError`` before the first
        batch with signal (no channel scales yet, so nothing could have been learned)."""
        if self._scale is None:
            raise ValueError("the model has seen no batch with signal yet: no channel scales, no regimes")
        return self._bank.state(self._scale)

    def load_bank(self, state: RegimeBankState) -> None:
        """Seed the bank with ``state`` (another run's :meth:`bank_state`), before the first batch with signal:
        the model adopts the channel scales the entries are in. ``ValueError`` (the model unchanged) when
        :func:`.arx_regime_bank.check_bank_state` refuses it or the model has already fixed other scales. The
        entries count as used now. The live model itself starts empty as before, but in the carried scales
        instead of its own first batch's (its ridge is relative to them)."""
        check_bank_state(self.cfg, state)
        if self._scale is not None and not np.array_equal(self._scale, state.scale):
            raise ValueError("the model has fixed its own channel scales already: load a bank before the first batch")
        if self._scale is None:
            # the past kept from silent batches goes into the same scaled units, as update() does when it fixes its own
            self._tail *= state.scale[:, None]
            self._tail_bp *= state.scale[:, None]
        self._scale = state.scale.astype(np.float64, copy=True)
        self._bank.load(state)

    def discount(self, gamma: float) -> None:
        """Weigh every sample regressed so far by ``γ`` more (``0 < γ ≤ 1``): a covariance reset after a change.

        In the square-root information form this is ``R ← √γ R`` (the
        information and the residual scale together, so ``θ`` is kept as a
        prior of weight ``γ``), then one QR with the rows
        ``(δ (1 − γ))^(1/2) [I_p | 0]`` that keep the ridge at ``δ``: the result
        equals the batch ridge least squares with the old rows weighted by
        ``γ`` (tested against ``numpy.linalg.lstsq``). Orthogonal operations
        only, fixed cost. The sample count (the model's fill) is kept."""
        if not 0.0 < gamma <= 1.0:
            raise ValueError(f"gamma must be in (0, 1], got {gamma}")
        self._absorb(gamma, None)
        self._weight_sum *= gamma

    def _absorb(self, decay: float, rows: NDArray[np.float64] | None) -> None:
        """``R ←`` the triangular factor of ``[√decay R; rows; (δ (1 − decay))^(1/2) [I_p | 0]]``, then ``θ``.

        Givens rotations in one defined order (:mod:`dsp_service.arx_kernel`):
        the same bits on every host; ``rows`` is consumed as scratch."""
        p = self.cfg.n_params
        r = self.R * math.sqrt(decay)
        if rows is not None:
            absorb_rows(r, rows)
        floor = math.sqrt(self.cfg.ridge * (1.0 - decay))
        if floor > 0.0:
            ridge = np.zeros((p, p + 1))
            ridge[:, :p] = floor * np.eye(p)
            absorb_rows(r, ridge)
        self.R = r
        theta = np.empty(p)
        back_substitute(r, theta)
        self.theta = theta

    def _decimate(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Every D-th sample by its running index (the phase carries across batches)."""
        d = self.cfg.decimation
        if d == 1:
            return x
        first = (-self._phase) % d
        self._phase = (self._phase + x.shape[1]) % d
        return x[:, first::d]

    def _sm_filter(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """Filter the (band-passed, decimated, scaled) channels by ``1/Â``.

        ``Â`` is the model's once it has filled its memory, its roots pulled in to
        ``|z| ≤ 0.97`` (bandwidth expansion ``Â(q) → Â(ρ q)``): the prefilter is
        always stable and never rings longer than ~33 model samples, whatever
        a spurious root of the model does; it only needs to approximate ``A``.
        """
        if self.samples >= 2.0 * min(self.cfg.memory_samples, 1e9):
            a = self.a
            r = float(np.max(np.abs(np.roots(a)))) if a.size > 1 and np.all(np.isfinite(a)) else float("nan")
            if np.isfinite(r):  # a non-finite model keeps the last prefilter
                rho = min(1.0, 0.97 / r) if r > 0 else 1.0
                self._sm_a = a * rho ** np.arange(a.size)
        xs, self._sm_zi = scipy.signal.lfilter([1.0], self._sm_a, x, axis=-1, zi=self._sm_zi)
        return cast(NDArray[np.float64], xs)

    def restart(self) -> None:
        """A gap in the data: keep the model, restart the filters and skip the regressors that span the gap."""
        self._zi.fill(0.0)
        self._sm_zi.fill(0.0)
        self._tail.fill(0.0)
        self._tail_bp.fill(0.0)
        self._skip = self._lag + int(2 * self.cfg.model_rate_hz / self.cfg.band_hz[0])

    # ---------------------------------------------------------------- model
    @property
    def a(self) -> NDArray[np.float64]:
        """``[1, a_1, …, a_na]``."""
        return np.concatenate([[1.0], self.theta[: self.cfg.na]])

    def b(self, i: int, j: int) -> NDArray[np.float64]:
        """``[0, b_ij,1, …, b_ij,nb]`` of input ``i`` → output ``j`` (0-based), in unscaled units."""
        c = self.cfg
        start = c.na + 2 * c.nb * j + c.nb * i
        coef = self.theta[start : start + c.nb]
        if self._scale is not None:
            coef = coef * self._scale[i] / self._scale[2 + j]
        return np.concatenate([[0.0], coef])

    def frequency_response(self, freqs_hz: NDArray[np.float64]) -> NDArray[np.complex128]:
        """``H`` ``(4, len(freqs))``, rows H11, H12, H21, H22 (input i → output j), of the model."""
        fs = self.cfg.model_rate_hz
        a = self.a
        out = []
        for i in range(2):
            for j in range(2):
                out.append(scipy.signal.freqz(self.b(i, j), a, worN=freqs_hz, fs=fs)[1])
        return np.array(out)

    def poles(self) -> tuple[ArxPole, ...]:
        """Modal poles of the current model, strongest first (see module doc)."""
        if self.samples == 0:
            return ()
        return modal_poles(self.cfg, self.a, np.stack([self.b(i, j) for i in range(2) for j in range(2)]))

    @property
    def fill(self) -> float:
        """How much of the memory the data since the reset fill, in [0, 1]."""
        mem = self.cfg.memory_samples
        return 1.0 if not math.isfinite(mem) and self.samples else min(1.0, self.samples / (2.0 * mem))
