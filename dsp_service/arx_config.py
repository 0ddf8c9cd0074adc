"""The recursive ARX model's configuration (:class:`.arx.RecursiveArx`, validated and immutable)."""

from __future__ import annotations

import math
from typing import Literal

import pydantic


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
