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

Regime bank (``regime_bank`` > 0, off by default). A plant that switches between
regimes it has shown before (the payload attached or not) need not be learned
again: the model keeps up to ``regime_bank`` snapshots of its own square-root
information ``(R, θ, σ²)`` taken when it ran calm, each named by its signature
(the frequencies of its first poles), and evaluates every snapshot's a-priori
equation errors ``y − φᵀθ_k`` on each batch's band-passed regression rows (before
the live model's ``1/Â``, which would favour the live model). When a snapshot
of another regime explains the batches markedly better than the live model
(short error power below ``bank_switch_ratio`` × the live one's in
``bank_switch_batches`` consecutive batches) the live information *becomes*
that snapshot, and the recursion continues from it (multiple-model switching;
the selection is the prediction-error comparison of the bank, not a separate
detector). Learned on line from the batches alone, bounded per batch
(``regime_bank`` × ``2 l p`` multiply-adds for the errors; a snapshot is a copy
of ``R``), and the information is still only ever replaced by the triangular
factor of a least-squares problem: nothing accumulates across hours.

Carried across runs (:meth:`RecursiveArx.bank_state`, :meth:`RecursiveArx.load_bank`,
:func:`save_regime_bank`, :func:`load_regime_bank`): what the bank learned in one run
(a calibration lap through the regimes, or yesterday's run of the same rig) seeds
the next, so a change into a regime the *rig* has shown before is followed within the
switch time even when the current run has not shown it yet. The state holds the
channel scales the entries' ``θ`` and ``R`` are in (the loading model adopts them
before its first batch) and the model structure it belongs to; a bank of another
structure is refused, never adapted.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, cast

import numpy as np
import pydantic
import scipy.signal
from numpy.typing import NDArray

from dsp_service import arx_kernel
from dsp_service.arx_kernel import absorb_rows, back_substitute, equation_errors


class ArxConfig(pydantic.BaseModel):
    """Parameters of :class:`RecursiveArx` (validated, immutable)."""

    model_config = pydantic.ConfigDict(frozen=True, extra="forbid")

    sample_rate_hz: float = pydantic.Field(200.0, gt=0)
    na: int = pydantic.Field(16, ge=2, le=40, description="Order of the common denominator A.")
    nb: int = pydantic.Field(12, ge=1, le=40, description="Order of each numerator B_ij.")
    forgetting: float = pydantic.Field(0.995, gt=0.5, le=1.0, description="Forgetting factor λ per sample (memory ≈ 1/(1 − λ) samples).")
    ridge: float = pydantic.Field(1e-4, gt=0, description="Constant ridge δ on the parameters (scaled data).")
    band_hz: tuple[float, float] = pydantic.Field((1.0, 30.0), description="Band-pass applied to all channels (Hz).")
    prefilter_order: int = pydantic.Field(2, ge=1, le=8, description="Butterworth order of the band-pass.")
    search_min_hz: float = pydantic.Field(0.5, ge=0)
    search_max_hz: float = pydantic.Field(40.0, gt=0)
    max_damping: float = pydantic.Field(0.5, gt=0, lt=1, description="Poles more damped than this are not modes.")
    min_relative_strength: float = pydantic.Field(0.1, ge=0, le=1, description="Drop poles whose modal peak is below this × the strongest's.")
    max_poles: int = pydantic.Field(4, ge=1, le=16)
    decimation: int = pydantic.Field(
        1, ge=1, le=16, description="Regress every D-th band-passed sample: the model runs at fs/D (the band-pass must end below its Nyquist)."
    )
    steiglitz_mcbride: bool = pydantic.Field(
        False,
        description="Filter the regression's channels by 1/Â (the current stable denominator): the equation error becomes the output error, "
        "which removes the ARX bias under white output noise (Steiglitz–McBride, recursive form).",
    )
    huber_k: float = pydantic.Field(
        0.0,
        ge=0,
        description="Bounded influence: a sample whose a-priori equation error exceeds k·σ (σ: the weighted residual rms) is "
        "down-weighted to k·σ (Huber); 0 = plain least squares.",
    )
    change_detection: bool = pydantic.Field(
        False,
        description="Detect a change of the plant (CUSUM of the log a-priori error level) and discount the old data at it: "
        "fast after a change, the forgetting factor's memory when steady.",
    )
    change_drift: float = pydantic.Field(1.0, gt=0, description="CUSUM drift ν per batch on ln(error level / its running mean).")
    change_threshold: float = pydantic.Field(5.0, gt=0, description="CUSUM alarm threshold h.")
    change_discount: float = pydantic.Field(0.01, gt=0, le=1, description="Weight γ left on the data before a detected change.")
    change_reference_s: float = pydantic.Field(5.0, gt=0, description="Span of the running mean of the log error level (s).")
    change_refractory_s: float = pydantic.Field(2.0, ge=0, description="No new alarm for this long after one (s).")
    order_by: Literal["strength", "frequency"] = pydantic.Field(
        "strength", description="Order of the reported poles: strongest first, or lowest frequency first (the first mode first)."
    )
    regime_bank: int = pydantic.Field(
        0,
        ge=0,
        le=8,
        description="Regimes the model remembers (0 = off): snapshots of its own settled information, learned on line; "
        "when a remembered model explains the current batches markedly better than the live one, the live one "
        "becomes it (a switch between plant regimes already seen, see the module doc).",
    )
    bank_error_s: float = pydantic.Field(0.2, gt=0, description="Time constant (s) of the error powers the bank compares.")
    bank_switch_ratio: float = pydantic.Field(
        0.7, gt=0, lt=1, description="Switch when a remembered model of another regime has an error power below this × the live model's ..."
    )
    bank_switch_batches: int = pydantic.Field(3, ge=1, description="... in this many consecutive batches.")
    bank_settle_s: float = pydantic.Field(
        4.0, gt=0, description="A snapshot is stored only after the live model has run this long calm (no switch, no error burst)."
    )
    bank_hold_s: float = pydantic.Field(
        1.0, ge=0, description="After a switch the remembered model is held unchanged this long (the change's transient is not in the model class)."
    )
    bank_signature_poles: int = pydantic.Field(2, ge=1, le=4, description="A regime's signature: its first this many poles' frequencies.")
    bank_signature_tol: float = pydantic.Field(
        0.03, gt=0, lt=0.5, description="Two models are the same regime when every signature pole agrees within this (relative)."
    )
    bank_calm_factor: float = pydantic.Field(
        3.0, gt=1, description="Calm: the live model's short error power is below this × its long-run level (over change_reference_s)."
    )

    @pydantic.model_validator(mode="after")
    def _check(self) -> ArxConfig:
        lo, hi = self.band_hz
        if not 0 < lo < hi < self.sample_rate_hz / 2:
            raise ValueError(f"band_hz must satisfy 0 < low < high < Nyquist, got {self.band_hz}")
        if hi >= self.model_rate_hz / 2:
            raise ValueError(f"band_hz must end below the decimated Nyquist {self.model_rate_hz / 2:g} Hz, got {self.band_hz}")
        if self.search_min_hz >= self.search_max_hz:
            raise ValueError("search_min_hz must be below search_max_hz")
        return self

    @property
    def model_rate_hz(self) -> float:
        """The model's sample rate ``fs / D``."""
        return self.sample_rate_hz / self.decimation

    @property
    def n_params(self) -> int:
        return self.na + 4 * self.nb

    @property
    def memory_samples(self) -> float:
        """Effective memory ``1/(1 − λ)`` (model samples, at ``fs / D``; inf without forgetting)."""
        return math.inf if self.forgetting >= 1.0 else 1.0 / (1.0 - self.forgetting)


@dataclass
class _Regime:
    """A remembered model: the live model's square-root information and residual scale at a calm moment."""

    R: NDArray[np.float64]
    theta: NDArray[np.float64]
    residual_power: float
    weight_sum: float
    used: int
    power: float = 0.0  #: its short a-priori error power on the current data (the bank's comparison)
    signature: NDArray[np.float64] | None = None  #: its first poles' frequencies (Hz): which regime it is


BANK_MODEL_FIELDS: tuple[str, ...] = (
    "sample_rate_hz",
    "na",
    "nb",
    "band_hz",
    "prefilter_order",
    "decimation",
    "steiglitz_mcbride",
    "forgetting",
    "ridge",
    "search_min_hz",
    "search_max_hz",
    "max_damping",
    "min_relative_strength",
    "max_poles",
    "order_by",
    "bank_signature_poles",
)
"""The :class:`ArxConfig` fields a remembered regime depends on: its ``R`` and ``θ`` (the model, its
forgetting and ridge) and its signature (the poles :meth:`RecursiveArx.poles` reports: the search band,
damping, strength, count and order). A bank carries them and is loaded only into a model whose fields
are equal."""

BANK_FILE_VERSION = 1
_BANK_ARRAYS = ("scale", "R", "theta", "residual_power", "weight_sum", "signature")
"""The float arrays of a :class:`RegimeBankState`, as a bank file holds them beside its version and model."""


@dataclass(frozen=True)
class RegimeBankState:
    """What a regime bank remembers, to seed another model (another run of the same rig).

    ``scale``: the channel scales (u1, u2, y1, y2) the entries are in; per entry ``k``:
    ``R[k]`` (upper-triangular ``(p + 1) × (p + 1)`` square-root information), ``theta[k]``,
    ``residual_power[k]``, ``weight_sum[k]`` and ``signature[k]`` (its first poles' Hz);
    ``model``: the :data:`BANK_MODEL_FIELDS` of the model that learned it."""

    model: dict[str, Any]
    scale: NDArray[np.float64]
    R: NDArray[np.float64]
    theta: NDArray[np.float64]
    residual_power: NDArray[np.float64]
    weight_sum: NDArray[np.float64]
    signature: NDArray[np.float64]

    @property
    def regimes(self) -> int:
        return int(self.theta.shape[0])


def bank_model_fields(cfg: ArxConfig) -> dict[str, Any]:
    """``cfg``'s :data:`BANK_MODEL_FIELDS` as plain JSON values (tuples as lists)."""
    dumped = cfg.model_dump(mode="json")
    return {k: dumped[k] for k in BANK_MODEL_FIELDS}


def save_regime_bank(path: str | Path, state: RegimeBankState) -> None:
    """Write ``state`` to an ``.npz`` file (no pickles; the model fields as JSON), crash-safe: into a
    temporary file of its own in the same directory, flushed to disk, then renamed over ``path`` (and the
    directory synced), so a stop or a power loss while writing leaves the previous bank, never part of one.
    On an error the temporary file is removed and the error raised."""
    target = Path(path)
    fd, tmp_name = tempfile.mkstemp(prefix=target.name + ".", suffix=".tmp", dir=target.parent)
    try:
        # mkstemp makes the file 0600: keep the mode of the bank it replaces, else what the umask gives a new file
        try:
            mode = target.stat().st_mode & 0o777
        except OSError:
            umask = os.umask(0)
            os.umask(umask)
            mode = 0o666 & ~umask
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as fh:
            np.savez(
                fh,
                version=np.array(BANK_FILE_VERSION),
                model=np.array(json.dumps(state.model, sort_keys=True)),
                **{k: getattr(state, k) for k in _BANK_ARRAYS},
            )
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp_name, target)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    try:  # the rename itself on disk (best effort: not every filesystem lets a directory be synced)
        dir_fd = os.open(target.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dir_fd)
    except OSError:
        pass
    finally:
        os.close(dir_fd)


def load_regime_bank(path: str | Path) -> RegimeBankState:
    """Read a bank written by :func:`save_regime_bank`; ``ValueError`` naming what is wrong with a file that is
    not one (unreadable, another version, missing or malformed arrays). Whether it fits a model is
    :meth:`RecursiveArx.load_bank`'s check."""
    try:
        with open(path, "rb") as fh:
            if fh.read(4) != b"PK\x03\x04":
                raise ValueError("not an .npz archive")
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:  # whatever a damaged or hand-made archive raises (zip, zlib, npy format errors) is a bad file
        raise ValueError(f"{path}: not a regime bank file ({type(exc).__name__}: {exc})") from None
    missing = [k for k in ("version", "model", *_BANK_ARRAYS) if k not in arrays]
    if missing:
        raise ValueError(f"{path}: not a regime bank file (missing {', '.join(missing)})")
    if not all(isinstance(v, np.ndarray) for v in arrays.values()):
        raise ValueError(f"{path}: not a regime bank file (a member is not an array)")
    version = arrays["version"]
    if version.ndim != 0 or version.dtype.kind not in "iu":
        raise ValueError(f"{path}: not a regime bank file (version is not an integer scalar)")
    if int(version) != BANK_FILE_VERSION:
        raise ValueError(f"{path}: regime bank version {int(version)}, this build reads {BANK_FILE_VERSION}")
    if arrays["model"].ndim != 0 or arrays["model"].dtype.kind != "U":
        raise ValueError(f"{path}: not a regime bank file (model is not a string)")
    try:
        model = json.loads(str(arrays["model"]))
    except (ValueError, RecursionError) as exc:
        raise ValueError(f"{path}: the bank's model fields are not JSON ({type(exc).__name__})") from None
    if not isinstance(model, dict):
        raise ValueError(f"{path}: the bank's model fields are not a JSON object")
    if any(arrays[k].dtype.kind not in "fiu" for k in _BANK_ARRAYS):
        raise ValueError(f"{path}: not a regime bank file (a numeric array holds something else)")
    f8 = {k: np.asarray(arrays[k], dtype=np.float64) for k in _BANK_ARRAYS}
    return RegimeBankState(model=model, **f8)


@dataclass(frozen=True)
class ArxPole:
    """One pole of the identified denominator."""

    frequency_hz: float  #: natural frequency |s|/2π
    damping_ratio: float  #: −Re s / |s|
    strength: float  #: modal peak √(Σ|r_ij|²)/(1 − |z|)
    relative_strength: float  #: strength / the strongest kept pole's


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
        self.change_statistic = 0.0  #: the change detector's CUSUM S
        self.changes_detected = 0  #: alarms since the reset (each discounted the model)
        self._ref_log = 0.0
        self._ref_count = 0
        self._since_alarm = 1 << 60
        self.bank: list[_Regime] = []  #: the remembered regimes (at most ``regime_bank``)
        self.bank_switches = 0  #: switches to a remembered regime since the reset
        self._live_power = 0.0  #: the live model's short error power (bank_error_s)
        self._live_level = 0.0  #: its long-run level (change_reference_s)
        self._calm = 0  #: model samples the live model has run calm since its last switch or burst
        self._pending: _Regime | None = None  #: the snapshot taken bank_settle_s ago, stored if calm since
        self._better_batches = 0  #: consecutive batches in which one remembered model of another regime explained the data markedly better
        self._frozen = 0  #: model samples the live model is still held unchanged after a switch
        self._clock = 0  #: model samples regressed (the bank's clock; an entry's last use)

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
        if c.change_detection and e is not None:
            self._detect_change(e, n)
        switched = False
        if c.regime_bank and e is not None:
            # compared on the band-passed rows before the live model's 1/Â: with the live prefilter the rows favour the
            # live model (after the release at 62 s in id-lag the remembered model then looked worse for ~1 s)
            rb = self._rows(ext_bp, n)
            eb = np.empty(2 * n)
            equation_errors(rb, self.theta, eb)
            switched = self._bank_step(rb, eb, n)
        if switched:
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
    def _snapshot(self) -> _Regime:
        return _Regime(self.R.copy(), self.theta.copy(), self.residual_power, self._weight_sum, self._clock)

    def _bank_step(self, rows: NDArray[np.float64], e: NDArray[np.float64], n: int) -> bool:
        """One batch of the regime bank (before the batch is absorbed); True when the live model switched.

        Every remembered model's a-priori equation errors on this batch's band-passed rows
        (``rows`` unweighted, before the ``1/Â`` prefilter; ``e`` the live model's on the same rows) give per model a short error
        power ``P ← β P + (1 − β) mean(e²)`` (``β = exp(−n / (τ f_m))``, τ
        ``bank_error_s``). **Switch**: a remembered ``P_k`` below
        ``bank_switch_ratio`` × the live ``P`` in ``bank_switch_batches``
        consecutive batches: the live information (``R``, ``θ``, σ²) becomes the
        remembered one. After a payload step the kick rings the new regime's
        second mode, which the new regime's ``A`` predicts and the old one's does
        not: its equation errors, not a detector, say which regime the data are in.
        **Store**: every ``bank_settle_s`` the live model's snapshot taken one
        period earlier is stored, if the live model ran *calm* all that period
        (short error power ≤ ``bank_calm_factor`` × its σ², no switch): into the
        remembered model whose error power is within a factor
        1/``bank_switch_ratio`` of the live one's (the same regime: refreshed),
        else as a new regime (the least recently used one evicted when full).
        Cost per batch: ``regime_bank`` × ``2n p`` multiply-adds; the bank is
        ``regime_bank`` copies of ``R``: bounded."""
        c = self.cfg
        beta = math.exp(-n / (c.bank_error_s * c.model_rate_hz))
        err = np.empty(2 * n)
        powers = []
        for reg in self.bank:
            equation_errors(rows, reg.theta, err)
            reg.power = beta * reg.power + (1.0 - beta) * float(np.mean(err * err))
            powers.append(reg.power)
        e2 = float(np.mean(e * e))
        self._live_power = beta * self._live_power + (1.0 - beta) * e2
        gamma = math.exp(-n / (c.change_reference_s * c.model_rate_hz))
        self._live_level = e2 if self._clock == 0 else gamma * self._live_level + (1.0 - gamma) * e2
        self._clock += n
        best = int(np.argmin(powers)) if powers else -1
        if (
            best >= 0
            and powers[best] < c.bank_switch_ratio * self._live_power
            and not self._same_regime(self.bank[best].signature, self._signature(self.theta))
        ):
            self._better_batches += 1
        else:
            self._better_batches = 0
        if self._better_batches >= c.bank_switch_batches:
            reg = self.bank[best]
            self.R = reg.R.copy()
            self.theta = reg.theta.copy()
            self.residual_power = reg.residual_power
            self._weight_sum = reg.weight_sum
            reg.used = self._clock
            self._live_power = reg.power
            self._better_batches = 0
            self._calm = 0
            self._pending = None
            self.bank_switches += 1
            return True
        if self._live_power <= c.bank_calm_factor * self._live_level:
            self._calm += n
        else:
            self._calm = 0
            self._pending = None
        period = int(round(c.bank_settle_s * c.model_rate_hz))
        if self._calm >= period:
            if self._pending is not None:
                self._store(self._pending)
            self._pending = self._snapshot()
            self._calm = 0
        return False

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

    def _same_regime(self, f: NDArray[np.float64] | None, g: NDArray[np.float64] | None) -> bool:
        """Two signatures name the same regime: every pole within ``bank_signature_tol`` (relative) of the other's."""
        if f is None or g is None:
            return False
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
            return False
        return bool(np.all(np.abs(f - g) <= self.cfg.bank_signature_tol * g))

    def _store(self, snap: _Regime) -> None:
        """``snap`` (taken one settle period ago) into the bank, if the live model still has its signature (it did not
        drift meanwhile: a settled regime, not a model half-way through a change): it refreshes the remembered regime
        with the same signature, else it is a new one (the least recently used evicted when the bank is full)."""
        c = self.cfg
        sig = self._signature(snap.theta)
        if not self._same_regime(sig, self._signature(self.theta)):
            return
        snap.signature = sig
        snap.power = self._live_power
        snap.used = self._clock
        match = [k for k, reg in enumerate(self.bank) if self._same_regime(sig, reg.signature)]
        if match:
            self.bank[match[0]] = snap
        elif len(self.bank) < c.regime_bank:
            self.bank.append(snap)
        else:
            k = min(range(len(self.bank)), key=lambda i: self.bank[i].used)
            self.bank[k] = snap

    def bank_state(self) -> RegimeBankState:
        """The bank as it stands, to seed another model (:meth:`load_bank`); ``ValueError`` before the first
        batch with signal (no channel scales yet, so nothing could have been learned)."""
        if self._scale is None:
            raise ValueError("the model has seen no batch with signal yet: no channel scales, no regimes")
        p, k = self.cfg.n_params, self.cfg.bank_signature_poles
        bank = self.bank
        return RegimeBankState(
            model=bank_model_fields(self.cfg),
            scale=self._scale.copy(),
            R=np.array([reg.R for reg in bank]).reshape(len(bank), p + 1, p + 1),
            theta=np.array([reg.theta for reg in bank]).reshape(len(bank), p),
            residual_power=np.array([reg.residual_power for reg in bank], dtype=np.float64),
            weight_sum=np.array([reg.weight_sum for reg in bank], dtype=np.float64),
            signature=np.array([reg.signature if reg.signature is not None else np.full(k, math.nan) for reg in bank]).reshape(len(bank), k),
        )

    def load_bank(self, state: RegimeBankState) -> None:
        """Seed the bank with ``state`` (another run's :meth:`bank_state`), before the first batch with signal:
        the model adopts the channel scales the entries are in. ``ValueError`` (the model unchanged) when the
        bank is off (``regime_bank`` 0), the model has already fixed other scales, the state belongs to
        another model structure (:data:`BANK_MODEL_FIELDS`) or holds more regimes than this bank keeps, or
        an entry is malformed (shapes, non-finite values, ``R`` not upper-triangular, a non-positive
        residual power). The entries count as used now. The live model itself starts empty as before, but in the
        carried scales instead of its own first batch's (its ridge is relative to them)."""
        c = self.cfg
        if not c.regime_bank:
            raise ValueError("this model keeps no regime bank (regime_bank 0)")
        mine = bank_model_fields(c)
        differ = sorted(k for k in BANK_MODEL_FIELDS if state.model.get(k) != mine[k])
        if differ:
            raise ValueError(
                "the bank was learned by another model structure: " + ", ".join(f"{k} {state.model.get(k)!r} (this model {mine[k]!r})" for k in differ)
            )
        p, k, n = c.n_params, c.bank_signature_poles, state.regimes
        if n > c.regime_bank:
            raise ValueError(f"the bank holds {n} regimes, this model keeps {c.regime_bank}")
        shapes = {"scale": (4,), "R": (n, p + 1, p + 1), "theta": (n, p), "residual_power": (n,), "weight_sum": (n,), "signature": (n, k)}
        for name, shape in shapes.items():
            got = getattr(state, name).shape
            if got != shape:
                raise ValueError(f"bank {name} has shape {got}, this model needs {shape}")
        if not (np.all(np.isfinite(state.scale)) and np.all(state.scale > 0)):
            raise ValueError("bank channel scales must be finite and positive")
        for name in ("R", "theta", "residual_power", "weight_sum"):
            if not np.all(np.isfinite(getattr(state, name))):
                raise ValueError(f"bank {name} holds non-finite values")
        if np.any(np.tril(state.R, -1) != 0.0):
            raise ValueError("bank R is not upper-triangular")
        if np.any(state.residual_power <= 0) or np.any(state.weight_sum <= 0):
            raise ValueError("bank residual powers and weight sums must be positive")
        if self._scale is not None and not np.array_equal(self._scale, state.scale):
            raise ValueError("the model has fixed its own channel scales already: load a bank before the first batch")
        if self._scale is None:
            # the past kept from silent batches goes into the same scaled units, as update() does when it fixes its own
            self._tail *= state.scale[:, None]
            self._tail_bp *= state.scale[:, None]
        self._scale = state.scale.astype(np.float64, copy=True)
        self.bank = [
            _Regime(
                state.R[i].copy(),
                state.theta[i].copy(),
                float(state.residual_power[i]),
                float(state.weight_sum[i]),
                self._clock,
                signature=state.signature[i].copy(),
            )
            for i in range(n)
        ]

    def _detect_change(self, e: NDArray[np.float64], n: int) -> None:
        """CUSUM of the log error ratio on the batch's a-priori errors ``e``; at an alarm, :meth:`discount`.

        ``z`` = the batch's mean of ``min(e²/σ², 50)`` (σ² the residual power),
        ``g = ln z − r`` with ``r`` the running mean of ``ln z`` over
        ``change_reference_s`` (the steady level: the a-priori errors of a model
        that fits stay near it whatever their distribution),
        ``S ← max(0, S + g − ν)``; ``S > h`` is a change (Page's test on a
        shift of the log error level). After an alarm the test rests for
        ``change_refractory_s`` (the new model converging raises the errors
        too). Detection starts once the reference has run for its own span."""
        c = self.cfg
        z = float(np.mean(np.minimum(e * e / self.residual_power, 50.0)))
        if not z > 0:
            return
        lz = math.log(z)
        ref_samples = c.change_reference_s * c.model_rate_hz
        if self._ref_count == 0:
            self._ref_log = lz
        g = lz - self._ref_log
        self._ref_log += (lz - self._ref_log) * min(1.0, n / ref_samples)
        self._ref_count += n
        self._since_alarm += n
        if self._ref_count < ref_samples or self._since_alarm < c.change_refractory_s * c.model_rate_hz:
            return
        self.change_statistic = max(0.0, self.change_statistic + g - c.change_drift)
        if self.change_statistic > c.change_threshold:
            self.change_statistic = 0.0
            self._since_alarm = 0
            self.changes_detected += 1
            self.discount(c.change_discount)

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
        c = self.cfg
        if self.samples == 0:
            return ()
        a = self.a
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
        bs = np.stack([self.b(i, j) for i in range(2) for j in range(2)])  # (4, nb + 1), ascending in q
        num = P.polyval(qk, bs.T)  # (4, K)
        strength = np.sqrt(np.sum(np.abs(num / den) ** 2, axis=0)) / np.maximum(1.0 - np.abs(zk), 1e-12)
        top = float(strength.max())
        rel = strength / top if top > 0 else np.zeros_like(strength)
        order = np.argsort(fn) if c.order_by == "frequency" else np.argsort(-strength)
        out = [ArxPole(float(fn[k]), float(zeta[k]), float(strength[k]), float(rel[k])) for k in order if rel[k] >= c.min_relative_strength]
        return tuple(out[: c.max_poles])

    @property
    def fill(self) -> float:
        """How much of the memory the data since the reset fill, in [0, 1]."""
        mem = self.cfg.memory_samples
        return 1.0 if not math.isfinite(mem) and self.samples else min(1.0, self.samples / (2.0 * mem))
