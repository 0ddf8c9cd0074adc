"""The recursive ARX model's regime bank: remembered models and the switch between them.

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

Carried across runs (:meth:`.arx.RecursiveArx.bank_state`, :meth:`.arx.RecursiveArx.load_bank`,
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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsp_service.arx_config import ArxConfig
from dsp_service.arx_kernel import equation_errors

Signature = Callable[[NDArray[np.float64]], NDArray[np.float64]]
"""The signature of a model ``θ``: the frequencies (Hz) of its first ``bank_signature_poles`` poles (NaN-padded)."""


@dataclass
class Regime:
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
forgetting and ridge) and its signature (the poles :meth:`.arx.RecursiveArx.poles` reports: the search band,
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
    :func:`check_bank_state`'s."""
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


def check_bank_state(cfg: ArxConfig, state: RegimeBankState) -> None:
    """``ValueError`` when ``state`` cannot seed a bank of a model of ``cfg``: the bank is off
    (``regime_bank`` 0), the state belongs to another model structure (:data:`BANK_MODEL_FIELDS`) or
    holds more regimes than this bank keeps, or an entry is malformed (shapes, non-finite values, ``R``
    not upper-triangular, a non-positive residual power)."""
    c = cfg
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


class RegimeBank:
    """The remembered regimes of one model and the bookkeeping of the switch (module doc)."""

    def __init__(self, cfg: ArxConfig) -> None:
        self.cfg = cfg
        self.regimes: list[Regime] = []  #: the remembered regimes (at most ``regime_bank``)
        self.switches = 0  #: switches to a remembered regime since the reset
        self.live_power = 0.0  #: the live model's short error power (bank_error_s)
        self._live_level = 0.0  #: its long-run level (change_reference_s)
        self._calm = 0  #: model samples the live model has run calm since its last switch or burst
        self._pending: Regime | None = None  #: the snapshot taken bank_settle_s ago, stored if calm since
        self._better_batches = 0  #: consecutive batches in which one remembered model of another regime explained the data markedly better
        self.clock = 0  #: model samples regressed (the bank's clock; an entry's last use)

    def step(
        self,
        rows: NDArray[np.float64],
        e: NDArray[np.float64],
        n: int,
        live_theta: NDArray[np.float64],
        signature: Signature,
        snapshot: Callable[[], Regime],
    ) -> Regime | None:
        """One batch of the regime bank (before the batch is absorbed); the remembered regime the live
        model is to become, else None.

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
        period earlier (``snapshot``) is stored, if the live model ran *calm* all that period
        (short error power ≤ ``bank_calm_factor`` × its σ², no switch): into the
        remembered model of the same signature (refreshed),
        else as a new regime (the least recently used one evicted when full).
        Cost per batch: ``regime_bank`` × ``2n p`` multiply-adds; the bank is
        ``regime_bank`` copies of ``R``: bounded."""
        c = self.cfg
        beta = math.exp(-n / (c.bank_error_s * c.model_rate_hz))
        err = np.empty(2 * n)
        powers = []
        for reg in self.regimes:
            equation_errors(rows, reg.theta, err)
            reg.power = beta * reg.power + (1.0 - beta) * float(np.mean(err * err))
            powers.append(reg.power)
        e2 = float(np.mean(e * e))
        self.live_power = beta * self.live_power + (1.0 - beta) * e2
        gamma = math.exp(-n / (c.change_reference_s * c.model_rate_hz))
        self._live_level = e2 if self.clock == 0 else gamma * self._live_level + (1.0 - gamma) * e2
        self.clock += n
        best = int(np.argmin(powers)) if powers else -1
        if best >= 0 and powers[best] < c.bank_switch_ratio * self.live_power and not self.same_regime(self.regimes[best].signature, signature(live_theta)):
            self._better_batches += 1
        else:
            self._better_batches = 0
        if self._better_batches >= c.bank_switch_batches:
            reg = self.regimes[best]
            reg.used = self.clock
            self.live_power = reg.power
            self._better_batches = 0
            self._calm = 0
            self._pending = None
            self.switches += 1
            return reg
        if self.live_power <= c.bank_calm_factor * self._live_level:
            self._calm += n
        else:
            self._calm = 0
            self._pending = None
        period = int(round(c.bank_settle_s * c.model_rate_hz))
        if self._calm >= period:
            if self._pending is not None:
                self._store(self._pending, live_theta, signature)
            self._pending = snapshot()
            self._pending.used = self.clock
            self._calm = 0
        return None

    def same_regime(self, f: NDArray[np.float64] | None, g: NDArray[np.float64] | None) -> bool:
        """Two signatures name the same regime: every pole within ``bank_signature_tol`` (relative) of the other's."""
        if f is None or g is None:
            return False
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(g))):
            return False
        return bool(np.all(np.abs(f - g) <= self.cfg.bank_signature_tol * g))

    def _store(self, snap: Regime, live_theta: NDArray[np.float64], signature: Signature) -> None:
        """``snap`` (taken one settle period ago) into the bank, if the live model still has its signature (it did not
        drift meanwhile: a settled regime, not a model half-way through a change): it refreshes the remembered regime
        with the same signature, else it is a new one (the least recently used evicted when the bank is full)."""
        sig = signature(snap.theta)
        if not self.same_regime(sig, signature(live_theta)):
            return
        snap.signature = sig
        snap.power = self.live_power
        snap.used = self.clock
        bank = self.regimes
        match = [k for k, reg in enumerate(bank) if self.same_regime(sig, reg.signature)]
        if match:
            bank[match[0]] = snap
        elif len(bank) < self.cfg.regime_bank:
            bank.append(snap)
        else:
            k = min(range(len(bank)), key=lambda i: bank[i].used)
            bank[k] = snap

    def state(self, scale: NDArray[np.float64]) -> RegimeBankState:
        """The bank as it stands in the channel scales ``scale``, to seed another model (:meth:`load`)."""
        p, k = self.cfg.n_params, self.cfg.bank_signature_poles
        bank = self.regimes
        return RegimeBankState(
            model=bank_model_fields(self.cfg),
            scale=scale.copy(),
            R=np.array([reg.R for reg in bank]).reshape(len(bank), p + 1, p + 1),
            theta=np.array([reg.theta for reg in bank]).reshape(len(bank), p),
            residual_power=np.array([reg.residual_power for reg in bank], dtype=np.float64),
            weight_sum=np.array([reg.weight_sum for reg in bank], dtype=np.float64),
            signature=np.array([reg.signature if reg.signature is not None else np.full(k, math.nan) for reg in bank]).reshape(len(bank), k),
        )

    def load(self, state: RegimeBankState) -> None:
        """The regimes of ``state`` (checked by :func:`check_bank_state`), each counted as used now."""
        self.regimes = [
            Regime(
                state.R[i].copy(),
                state.theta[i].copy(),
                float(state.residual_power[i]),
                float(state.weight_sum[i]),
                self.clock,
                signature=state.signature[i].copy(),
            )
            for i in range(state.regimes)
        ]
