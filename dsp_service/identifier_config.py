"""The identifier's configuration and what it reports: :class:`IdentifierConfig` (validated, immutable),
the ARX model's configuration derived from it, and the result types of a step and a download
(:class:`PoleEstimate`, :class:`IdentificationResult`, :class:`TransferFunctionEstimate`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, TypeVar

import numpy as np
import pydantic
from numpy.typing import NDArray

from .arx_config import ArxConfig

_Scalar = TypeVar("_Scalar", bound=np.generic)
PeakSource = Literal["tot", "11", "12", "21", "22"]
WELCH_PROFILE_SEGMENTS = 7  #: segments of method='etfe-welch' (512 samples each at N = 2048)


def arx_rate_and_band(sample_rate_hz: float, decimation: int, band_hz: tuple[float, float]) -> tuple[int, tuple[float, float]]:
    """The ARX model's decimation and band-pass for a loop at ``sample_rate_hz``.

    The settings name a band (2–15 Hz) and a decimation (4) chosen at the
    thesis's 200 Hz; at a lower rate the band's top is kept at most 0.35 fs and
    the decimation lowered until the band ends below 0.8 of the model's
    Nyquist (fs / D / 2), so every rate the settings allow builds a model (at
    200 Hz and above: the settings as given)."""
    lo, hi = band_hz
    hi = min(hi, 0.35 * sample_rate_hz)
    d = max(1, min(decimation, int(sample_rate_hz // (2.5 * hi))))
    return d, (min(lo, 0.5 * hi), hi)


def arx_config(c: IdentifierConfig) -> ArxConfig:
    """The recursive ARX model's configuration of ``method='arx'`` (the rig configuration, docs/identification.md §5)."""
    decimation, band = arx_rate_and_band(c.sample_rate_hz, c.arx_decimation, c.arx_band_hz)
    return ArxConfig(
        sample_rate_hz=c.sample_rate_hz,
        na=c.arx_na,
        nb=c.arx_nb,
        forgetting=c.arx_forgetting,
        decimation=decimation,
        band_hz=band,
        prefilter_order=c.arx_prefilter_order,
        steiglitz_mcbride=c.arx_steiglitz_mcbride,
        huber_k=c.arx_huber_k,
        max_damping=c.arx_max_damping,
        change_detection=c.arx_change_detection,
        regime_bank=c.arx_regime_bank,
        order_by="frequency",
        search_min_hz=c.search_min_hz,
        search_max_hz=c.search_max_hz,
        max_poles=c.max_peaks,
    )


class IdentifierConfig(pydantic.BaseModel):
    """Run-time parameters of the identifier (all validated; the model is immutable)."""

    model_config = pydantic.ConfigDict(frozen=True, extra="forbid")

    sample_rate_hz: float = pydantic.Field(200.0, gt=0, description="Sample rate of the batches (Hz).")
    fft_width: int = pydantic.Field(2048, ge=32, le=1 << 20, description="FFT width N = history length (even).")
    window: str = pydantic.Field("hann", description="scipy.signal.get_window name (periodic).")
    method: Literal["etfe", "etfe-welch", "etfe-transient", "arx"] = pydantic.Field(
        "etfe",
        description="Poles from the thesis's ETFE peak search; 'etfe-welch': the same with Welch "
        "within the history (welch_segments 7 unless given) and the rational-fit damping "
        "(damping_method 'fit' unless given); 'etfe-transient': the thesis's ETFE with the damping "
        "and natural frequency of the transient-aware fit of the history's DFT (damping_method "
        "'transient' unless given); 'arx': from the recursive QR-form ARX model "
        "(dsp_service.arx; the ETFE still serves the downloads).",
    )
    arx_forgetting: float = pydantic.Field(0.98, gt=0.5, le=1, description="ARX forgetting factor per model sample (at fs / arx_decimation).")
    arx_na: int = pydantic.Field(10, ge=2, le=40, description="ARX denominator order.")
    arx_nb: int = pydantic.Field(8, ge=1, le=40, description="ARX numerator order.")
    arx_decimation: int = pydantic.Field(4, ge=1, le=16, description="ARX model rate fs / D (the band-pass ends below its Nyquist).")
    arx_band_hz: tuple[float, float] = pydantic.Field((2.0, 15.0), description="ARX band-pass on every channel (Hz).")
    arx_prefilter_order: int = pydantic.Field(4, ge=1, le=8, description="Butterworth order of the ARX band-pass.")
    arx_steiglitz_mcbride: bool = pydantic.Field(True, description="ARX channels filtered by 1/Â (removes the equation-error bias).")
    arx_huber_k: float = pydantic.Field(1.5, ge=0, description="ARX bounded influence: errors beyond k·σ enter at k·σ (0: plain least squares).")
    arx_confident_strength: float = pydantic.Field(
        0.25,
        gt=0,
        le=1,
        description="An ARX pole's confidence is the model's fill times min(1, relative modal strength / this): "
        "a pole at least this strong relative to the strongest is fully confident (the second mode, which "
        "dominates link 2, is weaker than the first in the model's strength but well identified).",
    )
    arx_max_damping: float = pydantic.Field(0.25, gt=0, lt=1, description="ARX poles more damped than this are not modes.")
    arx_change_detection: bool = pydantic.Field(
        False,
        description="ARX change detector (CUSUM of the a-priori error level; discounts the old data at an alarm, "
        "dsp_service.arx). Off in the rig configuration: on the rig it gains less than the noise of the measure "
        "(docs/identification.md §5a).",
    )
    arx_regime_bank: int = pydantic.Field(
        0,
        ge=0,
        le=8,
        description="ARX regimes remembered on line (0 = off): the live model switches to a remembered one that explains "
        "the batches markedly better (dsp_service.arx, docs/identification.md §5c).",
    )
    averaging: Literal["exponential", "linear", "rls"] = pydantic.Field(
        "exponential",
        description="Spectra averaging: exponential [2-9], linear (equal weights, Welch), "
        "or per-bin RLS of the transfer functions [D.28, D.29] (forgetting rls_forgetting).",
    )
    alpha: float = pydantic.Field(0.1, gt=0, le=1, description="Exponential averaging weight α [2-9].")
    welch_segments: int = pydantic.Field(
        1,
        ge=1,
        le=15,
        description="1: one N-point window per snapshot (the C40). S > 1: Welch within the history, S "
        "half-overlapping windows of 2N/(S+1) samples zero-padded to N (more averages, coarser resolution).",
    )
    rls_forgetting: float = pydantic.Field(0.9, gt=0, le=1, description="RLS forgetting factor λ (≈ 1 − α).")
    rls_init_scale: float = pydantic.Field(1e8, gt=0, description="RLS initial inverse power, × 1/(mean input power of the first snapshot).")
    wait_for_full_history: bool = pydantic.Field(
        True,
        description="Average nothing until N samples have arrived since the last reset. The C40 "
        "ran on its zero-filled history from the start; a zero-to-signal step (e.g. joint "
        "angles of ~1 rad) then pollutes the averages for ~1/α iterations. False emulates the C40.",
    )
    solver: Literal["mimo", "uncorrelated"] = pydantic.Field("mimo", description="Corrected 2×2 solve [2-21…2-24] or H_ij = P_iyj/P_ii [2-25…2-28].")
    det_threshold: float = pydantic.Field(1e-3, ge=0, lt=1, description="Mask bins with (P11P22−|P12|²)/(P11P22) below this.")
    collinear: Literal["mask", "dominant"] = pydantic.Field(
        "dominant",
        description="Bins failing det_threshold (collinear inputs): 'mask' them (the C40) or solve them "
        "along the dominant input direction (rank-1 minimum norm, see mimo.py); mode per bin in downloads.",
    )
    power_floor: float = pydantic.Field(1e-12, ge=0, description="Mask bins whose input power is below this × mean input power.")
    smoothing_window: int = pydantic.Field(17, ge=0, description="Savitzky–Golay window in bins (odd; 0 or 1 = off).")
    smoothing_order: int = pydantic.Field(2, ge=0, description="Savitzky–Golay polynomial order.")
    peak_source: PeakSource = pydantic.Field("tot", description="Spectrum searched: H_tot or one H_ij.")
    log_weighting: bool = pydantic.Field(True, description="Rank peaks by |H|·(f/f_lo)^−γ (prefers low poles).")
    log_weight_exponent: float = pydantic.Field(0.5, ge=0, description="γ of the log weighting (−20γ dB/decade).")
    search_min_hz: float = pydantic.Field(0.5, ge=0, description="Lower edge of the peak search range (Hz).")
    search_max_hz: float = pydantic.Field(40.0, gt=0, description="Upper edge of the peak search range (Hz).")
    max_peaks: int = pydantic.Field(2, ge=1, le=16, description="Peaks reported (e.g. the two split poles).")
    min_peak_prominence_db: float = pydantic.Field(3.0, ge=0, description="Minimum prominence (dB, weighted magnitude) of a reported peak.")
    damping_method: Literal["vrm", "fwhm", "fit", "transient"] = pydantic.Field(
        "vrm",
        description="Which estimate PoleEstimate.damping_ratio reports: VRM, FWHM (each the other's "
        "fallback) or 'fit': a rational-fraction fit of the averaged FRF over ±fit_band_hz "
        "(dsp_service.ratfit; then frequency_hz is the fit's natural frequency; VRM, FWHM fall back); "
        "'transient': the local rational fit with the record's transient term of the unwindowed DFTs of "
        "the current history over ±fit_band_hz (dsp_service.modal.fit_mode_transient; likewise).",
    )
    fit_band_hz: float = pydantic.Field(1.0, gt=0, description="Half-width (Hz) of the band the 'fit' damping uses.")
    estimate_on_smoothed: bool = pydantic.Field(
        False,
        description="Refine peak frequency/magnitude and estimate damping on the smoothed "
        "spectrum (smoothing widens peaks: ζ biased up) instead of the averaged, unsmoothed one "
        "near the smoothed spectrum's peak.",
    )
    fwhm_exact: bool = pydantic.Field(True, description="FWHM: exact half-power inversion instead of ζ ≈ Δω/(2ω_p) [B.1].")
    vrm_model: Literal["viscous", "hysteretic"] = pydantic.Field("viscous", description="VRM reading of λ: viscous ζ = tan(arg λ/2), or [C-13, C-14].")
    vrm_band_factor: float = pydantic.Field(1.5, gt=0, description="VRM band half-width in half-power half-widths.")
    vrm_points_per_side: int = pydantic.Field(5, ge=1, le=10, description="At most this many VRM points each side of the peak (bounds the cost).")
    confidence_prominence_db: float = pydantic.Field(6.0, gt=0, description="Peak prominence (dB) at which the prominence factor of the confidence is 0.5.")

    @pydantic.model_validator(mode="before")
    @classmethod
    def _profile(cls, data: object) -> object:
        """``method='etfe-welch'`` fills its two settings unless they are given explicitly; the removed
        ``kernel`` is refused in one line."""
        if isinstance(data, dict) and "kernel" in data:
            raise ValueError("'kernel' was removed: the identifier has one step, the compiled one (dsp_service.kernel); drop the setting")
        if isinstance(data, dict) and data.get("method") == "etfe-welch":
            return {"welch_segments": WELCH_PROFILE_SEGMENTS, "damping_method": "fit", **data}
        if isinstance(data, dict) and data.get("method") == "etfe-transient":
            return {"damping_method": "transient", **data}
        return data

    @pydantic.model_validator(mode="after")
    def _check(self) -> IdentifierConfig:
        if self.fft_width % 2:
            raise ValueError("fft_width must be even")
        if self.welch_segments > 1 and self.averaging == "rls":
            raise ValueError("welch_segments > 1 averages spectra: not with averaging='rls'")
        if self.welch_segments > 1 and ((2 * self.fft_width) // (self.welch_segments + 1)) % 2:
            raise ValueError(f"{self.welch_segments} segments do not split N = {self.fft_width} into even halves")
        nyq = self.sample_rate_hz / 2.0
        if self.search_max_hz > nyq:
            raise ValueError(f"search_max_hz {self.search_max_hz} exceeds Nyquist {nyq}")
        if self.search_min_hz >= self.search_max_hz:
            raise ValueError("search_min_hz must be below search_max_hz")
        if (self.search_max_hz - self.search_min_hz) * self.fft_width / self.sample_rate_hz < 3:
            raise ValueError("search range spans fewer than 3 bins")
        if self.smoothing_window > 1:
            if self.smoothing_window % 2 == 0:
                raise ValueError("smoothing_window must be odd (or 0 = off)")
            if self.smoothing_order >= self.smoothing_window:
                raise ValueError("smoothing_order must be below smoothing_window")
            if self.smoothing_window > self.fft_width // 2 + 1:
                raise ValueError("smoothing_window exceeds the number of bins")
        return self


@dataclass(frozen=True)
class PoleEstimate:
    """One identified resonance."""

    frequency_hz: float  #: refined peak frequency (on the estimation spectrum, see estimate_on_smoothed)
    damping_ratio: float  #: the configured method's ζ, else the other's, else 0.0 (see damping_defined)
    damping_fwhm: float | None  #: half-power width (exact or [B.1]); None if no crossings in range
    damping_vrm: float | None  #: VRM median ζ; None if no physical triplet
    natural_frequency_vrm_hz: float | None  #: VRM ω_n/2π
    magnitude: float  #: |H| at the refined peak
    prominence_db: float  #: prominence on the weighted magnitude
    source: str  #: "tot", "11", "12", "21", "22" or "arx"
    damping_defined: bool = True  #: False when neither FWHM nor VRM gave a value (damping_ratio = 0.0)
    confidence: float = 0.0  #: this pole's confidence in [0, 1] (module doc)
    damping_fit: float | None = None  #: ζ of the rational-fraction fit (damping_method 'fit' or 'transient'); None otherwise or if unphysical


@dataclass(frozen=True)
class IdentificationResult:
    """Output of one C40 iteration."""

    poles: tuple[PoleEstimate, ...]  #: best (weighted) first
    confidence: float  #: in [0, 1], see module doc
    valid_fraction: float  #: valid smoothed bins in the search range
    samples_in_history: int
    effective_averages: float


@dataclass(frozen=True)
class TransferFunctionEstimate:
    """Current (smoothed unless requested raw) transfer-function estimates; arrays are read-only."""

    freqs_hz: NDArray[np.float64]
    h11: NDArray[np.complex128]
    h12: NDArray[np.complex128]
    h21: NDArray[np.complex128]
    h22: NDArray[np.complex128]
    htot: NDArray[np.complex128]
    valid: NDArray[np.bool_]
    #: per bin the solve used: 0 masked, 1 dominant input direction (collinear), 2 full 2×2 (mimo.MODE_*)
    mode: NDArray[np.uint8] | None = None

    # the names used on the wire (TfSnapshot): H11 … Htot
    @property
    def H11(self) -> NDArray[np.complex128]:
        return self.h11

    @property
    def H12(self) -> NDArray[np.complex128]:
        return self.h12

    @property
    def H21(self) -> NDArray[np.complex128]:
        return self.h21

    @property
    def H22(self) -> NDArray[np.complex128]:
        return self.h22

    @property
    def Htot(self) -> NDArray[np.complex128]:
        return self.htot


def readonly(a: NDArray[_Scalar]) -> NDArray[_Scalar]:
    a.flags.writeable = False
    return a
