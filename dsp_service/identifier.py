"""The C40 identifier's façade: one call per batch, as in thesis §3.2.3 (the service calls this).

One :meth:`Identifier.step` is one C40 iteration on the current history:

1. detrended, windowed FFTs of the four channels (:mod:`.spectra`);
2. the seven raw auto/cross spectra, averaged *before* the solve —
   exponential [2-9], equal-weight (Welch) or, with ``averaging='rls'``,
   per-bin RLS of the transfer functions ([1-9, 1-10], [D.15–D.29]);
3. the 2×2 solve, corrected [2-21 … 2-24] or uncorrelated [2-25 … 2-28],
   with masking of ill-conditioned bins (:mod:`.mimo`); ``H_tot`` = mean;
4. Savitzky–Golay smoothing across frequency (§2.4.1, :mod:`.smoothing`)
   of the searched spectrum, over the search range only;
5. peak search (log-weighted global maximum, up to ``max_peaks`` peaks),
   damping by VRM [C-12 … C-14] and FWHM [B.1]/exact (:mod:`.modal`).

Confidence ∈ [0, 1] is the product of four factors (each in [0, 1]):

* ``valid_fraction`` — the fraction of search-range bins whose smoothed
  estimate is valid (no masked raw bin in its smoothing window);
* ``1 − 1/n_eff`` — ``n_eff`` the effective number of averages (see
  :class:`.spectra.SpectralAverager`): 0 for a single snapshot, whose MIMO
  solve is undefined; 0.9 at 10 averages;
* history fill — ``samples_in_history / N`` (zero-padded history early on);
* peak prominence — ``p / (p + p₀)`` with ``p`` the primary peak's
  prominence in dB on the weighted magnitude and ``p₀ =
  confidence_prominence_db`` (0.5 at ``p = p₀``); 0 when no peak.

Each pole also carries its own confidence: the first three factors times
its own prominence factor. ``method='arx'`` reports the poles of the
recursive ARX model instead (:mod:`.arx`; confidence = the model's fill
times the pole's relative modal strength); ``'etfe-welch'`` is the ETFE
with Welch segments within the history and the rational-fraction damping
(:mod:`.ratfit`); collinear bins are solved along the dominant input
direction (:mod:`.mimo`, ``collinear``). See docs/identification.md.

No NaN or inf ever leaves this module: masked bins are exactly 0; an
undefined FWHM or VRM damping is ``None``, and ``damping_ratio`` is then
the other method's value, or 0.0 with ``damping_defined=False``.

Deliberate deviations from the C40 (each a config switch): averaging waits
for a full history (``wait_for_full_history``); pole frequency, magnitude
and damping are estimated on the averaged *unsmoothed* spectrum around the
smoothed spectrum's peak (``estimate_on_smoothed=False``), because the
thesis's 17-bin smoothing of 0.098 Hz bins widens a ζ = 0.09 peak at 3.6 Hz
by ~80 % and shifts it by ~1.5 bins; VRM reads λ as a viscous mode
(``vrm_model``).

Cost (see :mod:`.bench`): everything that depends only on the
configuration (windows, frequency grids, weights, smoothing rows, views of
the averaged spectra) is prepared in ``_build``. A step is one compiled
detrend/window pass, the four FFTs (``scipy.fft.rfft``) and one compiled call
(:func:`.kernel.step_packed`: averaging, the ``H_tot`` solve with its dominant
branch, smoothing, peak search, refinement, FWHM and VRM), compiled when the
Identifier is built. ``welch_segments`` > 1 averages the segmented spectra
(:mod:`.spectra`) before the compiled solve; ``averaging='rls'``,
``solver='uncorrelated'`` and a ``peak_source`` other than ``'tot'`` average
with the compiled averaging alone, solve with :mod:`.mimo` (and the RLS) and
enter the compiled call at its smoothing; the rational fits
(``damping_method`` 'fit', 'transient') run on its poles.
The peak search ranks the linear weighted magnitude ``|H|·w`` (the same
order, maxima and prominence bases as ``20 log10|H| + w_dB``, without the
logarithms). The tests hold the step to scipy (``csd``, ``savgol_filter``,
``find_peaks``) and to numpy's linear algebra (tests/dsp/test_fast_paths.py,
test_scipy_equivalence.py, test_collinear.py).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal, TypeVar

import numpy as np
import pydantic
from numpy.typing import NDArray

from .arx import RecursiveArx
from .arx_config import ArxConfig
from .arx_regime_bank import RegimeBankState
from .history import HistoryBuffer
from .mimo import H_NAMES, MimoSolver, ScalarRLS, VectorRLS
from .modal import (
    PeakRefiner,
    VrmEstimator,
    fit_mode_transient,
    log_weights,
)
from .ratfit import fit_mode
from .smoothing import FrequencySmoother
from .spectra import (
    SPECTRA_NAMES,
    SegmentedSpectralEstimator,
    SpectralAverager,
    SpectralEstimator,
    rfft_rows,
    scale_spectra,
    welch_equivalent_averages,
)

log = logging.getLogger(__name__)

_TINY = float(np.finfo(np.float64).tiny)
_EST_MARGIN_BINS = 32  #: bins solved beyond the search range for FWHM/VRM near its edges
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


def _readonly(a: NDArray[_Scalar]) -> NDArray[_Scalar]:
    a.flags.writeable = False
    return a


class Identifier:
    """Pure, synchronous 2-input 2-output on-line identifier (the emulated C40)."""

    def __init__(self, cfg: IdentifierConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else IdentifierConfig()
        self._arx_seed: RegimeBankState | None = None
        self._arx: RecursiveArx | None = None
        self._build()

    # ------------------------------------------------------------ configure
    def _build(self) -> None:
        """(Re)allocate everything that depends only on the configuration. The regimes an ARX bank has
        learned are the plant's, not the history's: a rebuilt model starts from them (else from the bank
        carried in, :meth:`seed_arx_bank`)."""
        carried = self.arx_bank_state()
        c = self.cfg
        n = c.fft_width
        self.history = HistoryBuffer(n)
        if c.welch_segments > 1:
            self._est: SpectralEstimator = SegmentedSpectralEstimator(n, c.sample_rate_hz, c.window, c.welch_segments)
            self._seg_avgs = welch_equivalent_averages(c.welch_segments)
        else:
            self._est = SpectralEstimator(n, c.sample_rate_hz, c.window)
            self._seg_avgs = 1.0
        k = self._est.n_bins
        self.freqs = self._est.freqs
        if c.averaging == "rls":
            # input spectra for the mask, with the RLS's own weighting (α = 1 − λ)
            lam = c.rls_forgetting
            self._avg = SpectralAverager((7, k), n, "linear" if lam >= 1.0 else "exponential", min(1.0, 1.0 - lam) or 1.0)
            cls = VectorRLS if c.solver == "mimo" else ScalarRLS
            self._rls: ScalarRLS | VectorRLS | None = cls(k, c.rls_forgetting, c.rls_init_scale)
        else:
            self._avg = SpectralAverager((7, k), n, c.averaging, c.alpha)
            self._rls = None
        self._solver = MimoSolver(k, c.solver, c.det_threshold, c.power_floor, c.collinear)
        self._smoother = FrequencySmoother(k, c.smoothing_window, c.smoothing_order)
        df = c.sample_rate_hz / n
        self._lo = max(1, math.ceil(c.search_min_hz / df - 1e-9))
        self._hi = min(k, math.floor(c.search_max_hz / df + 1e-9) + 1)
        self._f_range = self.freqs[self._lo : self._hi]
        f_ref = max(c.search_min_hz, df)
        # the peak search ranks |H|·w on a linear scale (the same order and the same
        # peaks as 20 log10|H| + 20 log10 w in dB); prominences become ratios
        self._w_lin = log_weights(self._f_range, f_ref, c.log_weight_exponent) if c.log_weighting else None
        self._prom_ratio = 10.0 ** (c.min_peak_prominence_db / 20.0)
        n_range = self._hi - self._lo
        self._vrm = VrmEstimator(c.vrm_points_per_side, c.vrm_band_factor, model=c.vrm_model)
        self._refiner = PeakRefiner()
        h = self._smoother.half
        self._relocate = max(1, h // 2)
        # bins solved each step: the search range plus a margin for the smoothing
        # windows and the damping estimators (FWHM crossings, VRM band)
        margin = max(2 * h + 1, _EST_MARGIN_BINS)
        self._sl = slice(max(0, self._lo - margin), min(k, self._hi + margin))
        self._f_sl = self.freqs[self._sl]
        self._n_sl = self._sl.stop - self._sl.start
        self._rls_src = np.zeros(k, dtype=np.complex128)
        if self._rls is not None:
            src = self._rls_src
        elif c.peak_source == "tot":
            src = self._solver.source
        else:
            src = self._solver.H[H_NAMES.index(c.peak_source)]
        self._src = src
        # where the compiled step starts (kernel.step_packed): 1 averages the snapshot's FFTs and
        # solves H_tot; 2 solves H_tot of the averages the (segmented) estimator made; 3 searches
        # the spectrum the RLS, the uncorrelated solve or one H_ij gives
        if self._rls is None and c.solver == "mimo" and c.peak_source == "tot":
            self._first_stage = 1 if c.welch_segments == 1 else 2
        else:
            self._first_stage = 3
        self._build_kernel(n_range)
        self._pending = 0
        self._arx = None
        self._arx_batches: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        if c.method == "arx":
            self._arx = RecursiveArx(arx_config(c))
            seed = carried if carried is not None and carried.regimes else self._arx_seed
            if seed is not None:
                try:
                    self._arx.load_bank(seed)
                except ValueError as exc:  # not expected (the same model fields); never let a rebuild fail half-way
                    log.warning("the rebuilt ARX model starts without its regime bank: %s", exc)

    def _build_kernel(self, n_range: int) -> None:
        """Buffers and the per-bin smoothing rows of the compiled step (:mod:`.kernel`), compiled here."""
        from . import kernel

        lo, hi, k = self._lo, self._hi, self._est.n_bins
        self._k_coef, self._k_starts, self._k_ia, self._k_ib = self._smoothing_rows(n_range)
        self._k_ffts_f = self._est.ffts.view(np.float64)  # (re, im) float view for the averaging
        self._k_zeros_f = np.zeros_like(self._k_ffts_f)
        self._k_hs = np.empty(n_range, dtype=np.complex128)
        self._k_vs = np.empty(n_range, dtype=bool)
        self._k_w = self._w_lin if self._w_lin is not None else np.ones(n_range)
        ref, vrm = self._refiner, self._vrm
        r_max = ref.r_max
        self._k_pinv = np.zeros((r_max + 1, 3, 2 * r_max + 1))
        for r, pinv in ref._pinv.items():
            self._k_pinv[r, :, : 2 * r + 1] = pinv
        tris = vrm._triplets
        self._k_ntri = np.array([t.shape[0] for t in tris], dtype=np.intp)
        self._k_tri = np.zeros((len(tris), max(1, int(self._k_ntri.max())), 3), dtype=np.intp)
        for m, t in enumerate(tris):
            self._k_tri[m, : t.shape[0]] = t
        self._k_mag = np.empty(max(self._n_sl, n_range))
        kernel.warm_up()
        # Every argument of the compiled step but the snapshot and its weight is fixed
        # until the next _build: packed once here, so a step makes one call of 11
        # arguments to the compiled overload itself (no per-call type resolution).
        c, sl = self.cfg, self._sl
        fp = np.zeros(kernel.N_FP)
        fp[kernel.FP_POWER_FLOOR], fp[kernel.FP_DET], fp[kernel.FP_RATIO] = c.power_floor, c.det_threshold, self._prom_ratio
        fp[kernel.FP_BAND], fp[kernel.FP_ZETA_MAX], fp[kernel.FP_C_MAX] = vrm.band_factor, vrm.zeta_max, vrm._im_over_re_max
        ip = np.zeros(kernel.N_IP, dtype=np.intp)
        for i, value in (
            (kernel.IP_BINS, k),
            (kernel.IP_S0, sl.start),
            (kernel.IP_S1, sl.stop),
            (kernel.IP_DOMINANT, c.collinear == "dominant"),
            (kernel.IP_LO, lo),
            (kernel.IP_HI, hi),
            (kernel.IP_IA, self._k_ia),
            (kernel.IP_IB, self._k_ib),
            (kernel.IP_WEIGHTED, self._w_lin is not None),
            (kernel.IP_WANT, c.max_peaks),
            (kernel.IP_FIRST, self._first_stage),
            (kernel.IP_ON_SMOOTHED, c.estimate_on_smoothed),
            (kernel.IP_RELOCATE, self._relocate),
            (kernel.IP_FWHM_EXACT, c.fwhm_exact),
            (kernel.IP_R_MAX, r_max),
            (kernel.IP_M_MAX, vrm.m_max),
            (kernel.IP_VISCOUS, vrm.model == "viscous"),
        ):
            ip[i] = int(value)
        solver = self._solver
        # the constants, scratch and outputs packed into three flat arrays (kernel.pack_arguments);
        # the attributes become views into them, so the Python side reads the same names
        fk, ik, fw, views = kernel.pack_arguments(
            fp,
            ip,
            self._k_coef,
            self._k_w,
            self._f_sl,
            self._f_range,
            self._k_pinv,
            self._k_starts,
            self._k_tri,
            self._k_ntri,
            self._k_mag.size,
        )
        self._k_coef, self._k_w, self._k_pinv = views["coef"], views["w_lin"], views["pinv"]
        self._k_starts, self._k_tri, self._k_ntri, self._k_order = views["starts"], views["tri"], views["n_tri"], views["order"]
        self._k_idx, self._k_prom, self._k_stats, self._k_mag, self._k_out = views["idx"], views["prom"], views["stats"], views["mag"], views["out"]
        self._k_v = views["v"]
        self._k_args = (fk, ik, fw, self._avg.state, self._src, solver.valid, solver.mode, self._k_hs, self._k_vs)
        # resolved with no snapshot (weight 0 on a zero state: nothing changes)
        self._k_call = kernel.compiled_entry(kernel.step_packed, (self._k_zeros_f, 0.0, *self._k_args))
        est = self._est
        self._k_fft_args = (est._tmp, est.ffts)
        self._k_dtr_args = (est.means, est.window, est._tmp)
        self._k_detrend_ring = kernel.compiled_entry(kernel.detrend_window_ring, (self.history._buf, 0, *self._k_dtr_args))
        self._k_state_f = self._avg.state.view(np.float64)
        # the averaging alone (settings whose solve runs before the compiled search): resolved on a
        # zero snapshot of weight 0, which leaves the state as it is
        self._k_accumulate = kernel.compiled_entry(kernel._accumulate, (self._k_zeros_f, 0.0, self._k_state_f))
        # what _step_etfe reads of the configuration (fixed until the next _build; set_alpha changes none of it)
        self._k_early = not c.wait_for_full_history
        self._k_want, self._k_n_range, self._k_tail = c.max_peaks, n_range, views["tail"]
        self._k_pole_consts = (c.confidence_prominence_db, c.damping_method != "fwhm", c.peak_source)
        self._k_fit = c.damping_method in ("fit", "transient")

    def _smoothing_rows(self, n_range: int) -> tuple[NDArray[np.float64], NDArray[np.intp], int, int]:
        """``(coef, starts, ia, ib)`` of the compiled smoothing: its rows and window starts over the
        search range, and its interior ``ia … ib`` (rows of one sliding window, the centre row)."""
        sm, lo, hi, k = self._smoother, self._lo, self._hi, self._est.n_bins
        if sm.enabled:
            h = sm.half
            rows = []
            for i in range(lo, hi):
                if i < h:
                    rows.append(sm.edge_lo[i])
                elif i >= k - h:
                    rows.append(sm.edge_hi[i - (k - h)])
                else:
                    rows.append(sm.centre)
            coef = np.ascontiguousarray(np.stack(rows), dtype=np.float64)
            starts = np.ascontiguousarray(sm._starts[lo:hi], dtype=np.intp)
        else:
            coef = np.ones((n_range, 1))
            starts = np.arange(lo, hi, dtype=np.intp)
        steps = np.flatnonzero(np.diff(starts) == 1)  # consecutive rows of a sliding window
        if not steps.size:
            return coef, starts, 0, 0
        ia, ib = int(steps[0]), int(steps[-1]) + 2
        # the kernel's interior passes need a sliding window of one row (the centre row)
        if not (np.array_equal(starts[ia:ib], starts[ia] + np.arange(ib - ia)) and (coef[ia:ib] == coef[ia]).all()):
            return coef, starts, 0, 0
        return coef, starts, ia, ib

    def warm_up(self) -> None:
        """Compile (or load from numba's cache) the compiled step; the constructor already does."""
        from . import kernel

        kernel.warm_up()

    def set_fft_width(self, n: int) -> None:
        """Change N: zeroes the history and every average (as on the C40)."""
        self.cfg = IdentifierConfig.model_validate({**self.cfg.model_dump(), "fft_width": n})
        self._build()

    def reset(self) -> None:
        """Zero the history and the averages, keeping the configuration (and what an ARX regime bank learned)."""
        self._build()

    def restart_history(self) -> None:
        """Zero the history only (e.g. after lost batches); the averages are kept.

        With ``wait_for_full_history`` nothing new is averaged until ``N``
        contiguous samples have arrived again, so the gap never enters a snapshot.
        """
        self.history.clear()
        self._pending = 0
        self._arx_batches.clear()
        if self._arx is not None:
            self._arx.restart()

    def set_alpha(self, alpha: float) -> None:
        """Change the averaging weight α at run time without disturbing history or averages.

        With ``averaging='rls'`` this sets the forgetting factor λ = 1 − α.
        """
        upd: dict[str, float] = {"alpha": alpha}
        if self.cfg.averaging == "rls":
            upd["rls_forgetting"] = 1.0 - alpha
        self.cfg = IdentifierConfig.model_validate({**self.cfg.model_dump(), **upd})
        if self.cfg.averaging == "exponential":
            self._avg.alpha = self.cfg.alpha
        elif self.cfg.averaging == "rls":
            lam = self.cfg.rls_forgetting
            assert self._rls is not None
            self._rls.lam = lam
            if lam < 1.0:  # the mask's input spectra keep the RLS's weighting
                self._avg.method, self._avg.alpha = "exponential", 1.0 - lam
            else:
                self._avg.method = "linear"

    @property
    def fft_width(self) -> int:
        """Current FFT width N (= history length)."""
        return self.cfg.fft_width

    # ----------------------------------------------------------------- data
    def push(self, inputs: NDArray[np.float64], outputs: NDArray[np.float64]) -> None:
        """Append a batch: ``inputs`` (u1, u2) and ``outputs`` (y1, y2), each ``(2, l)``."""
        before = self.history.samples_seen
        self.history.append(inputs, outputs)
        self._pending += self.history.samples_seen - before
        if self._arx is not None:
            self._arx_batches.append((np.asarray(inputs, dtype=np.float64), np.asarray(outputs, dtype=np.float64)))

    @property
    def samples_in_history(self) -> int:
        return self.history.samples_in_history

    # ----------------------------------------------------------------- step
    def step(self) -> IdentificationResult:
        """One iteration: the ETFE's (below), with ``method='arx'`` the ARX model's poles instead."""
        result = self._step_etfe()
        if self._arx is None:
            return result
        arx = self._arx
        for u, y in self._arx_batches:
            arx.update(u, y)
        self._arx_batches.clear()
        fill = arx.fill
        poles = tuple(
            PoleEstimate(
                frequency_hz=p.frequency_hz,
                damping_ratio=p.damping_ratio,
                damping_fwhm=None,
                damping_vrm=None,
                natural_frequency_vrm_hz=None,
                magnitude=p.strength,
                prominence_db=20.0 * math.log10(max(p.relative_strength, 1e-12)),
                source="arx",
                confidence=fill * min(1.0, p.relative_strength / self.cfg.arx_confident_strength),
            )
            for p in arx.poles()
        )
        return IdentificationResult(
            poles=poles,
            confidence=fill if poles else 0.0,
            valid_fraction=result.valid_fraction,
            samples_in_history=result.samples_in_history,
            effective_averages=result.effective_averages,
        )

    @property
    def arx(self) -> RecursiveArx | None:
        """The recursive ARX model (``method='arx'``), else None."""
        return self._arx

    def seed_arx_bank(self, state: RegimeBankState) -> None:
        """Seed the ARX model's regime bank with another run's (:meth:`RecursiveArx.load_bank`, before the first
        batch), and again whenever the model is rebuilt; ``ValueError`` without an ARX model with a bank, or for
        a bank that does not fit it (the model unchanged)."""
        if self._arx is None:
            raise ValueError("a regime bank needs identifier 'arx'")
        self._arx.load_bank(state)
        self._arx_seed = state

    def arx_bank_state(self) -> RegimeBankState | None:
        """The ARX model's regime bank as it stands (to carry into another run), None without an ARX model,
        without a bank or before its first batch with signal."""
        arx = self._arx
        if arx is None or not arx.cfg.regime_bank:
            return None
        try:
            return arx.bank_state()
        except ValueError:
            return None

    def _step_etfe(self) -> IdentificationResult:
        """One C40 iteration on the current history (module doc): one compiled call
        (:func:`.kernel.step_packed`) from the stage the configuration needs, the segmented
        spectra, the RLS and the solves other than the corrected ``H_tot`` made before it here.

        With an empty history (nothing pushed since the last reset), or with
        ``wait_for_full_history`` before N samples have arrived, nothing is
        averaged; until the first average an empty result is returned.
        Everything the call needs but the snapshot and its weight is fixed until the next
        :meth:`_build` and read from a few prepared tuples (``_k_*``); the kernel's counters,
        prominences and poles are read with one ``tolist`` (``_k_tail``)."""
        hist, avg = self.history, self._avg
        seen, n_hist = hist._seen, hist._n  # hist.samples_seen, hist.n (the properties, without their calls)
        first = self._first_stage
        if seen > 0 and (seen >= n_hist or self._k_early):
            if self._seg_avgs == 1.0:  # one window per snapshot: the compiled detrend and averaging
                weight = avg.take(self._pending)  # next_weight and the bookkeeping: the kernel adds the snapshot
                self._pending = 0
                # detrend='constant', then window (scipy.signal.csd's order)
                self._k_detrend_ring(hist._buf, hist._head, *self._k_dtr_args)
                rfft_rows(*self._k_fft_args)
                if first == 1:
                    self._k_call(self._k_ffts_f, weight, *self._k_args)
                else:
                    self._k_accumulate(self._k_ffts_f, weight, self._k_state_f)
                    if self._rls is not None:
                        self._rls.update(self._est.ffts)
                    self._solve_searched()
                    self._k_call(self._k_zeros_f, 0.0, *self._k_args)
            else:  # Welch segments within the history
                est = self._est
                assert isinstance(est, SegmentedSpectralEstimator)
                weight = avg.next_weight()
                avg.add(est.snapshot(hist.view(), weight), self._pending)
                self._pending = 0
                self._solve_searched()
                self._k_call(self._k_zeros_f, 0.0, *self._k_args)
        elif avg.updates == 0:
            return IdentificationResult((), 0.0, 0.0, min(seen, n_hist), 0.0)
        else:  # no new snapshot: solve the averages as they are
            self._solve_searched()
            self._k_call(self._k_zeros_f, 0.0, *self._k_args)
        want = self._k_want
        vals = self._k_tail.tolist()  # prominences[want], stats[4], poles[want × 6]
        f_sl_valid, f_valid, f_nf, floor = vals[want : want + 4]
        solver = self._solver
        if first < 3:
            solver._floor = floor
        solver.valid_count = n_sl_valid = int(f_sl_valid)
        n_valid, nf = int(f_valid), int(f_nf)
        n_range = self._k_n_range
        if nf == 0:
            return IdentificationResult((), 0.0, n_valid / n_range, hist.samples_in_history, float(self.effective_averages))
        # the confidences, computed before the poles are made
        # (self.effective_averages, SpectralAverager.effective_averages, inline)
        if self._seg_avgs > 1.0:
            n_eff = self.effective_averages
        else:
            sum_c, sum_c2 = avg._sum_c, avg._sum_c2
            kish = sum_c * sum_c / sum_c2 if sum_c2 > 0.0 else 0.0
            n_eff = min(kish, 1.0 + 2.0 * (avg._sum_cl / sum_c) * (kish - 1.0) / avg.n) if kish != 0.0 else 0.0
        valid_fraction = n_valid / n_range
        in_history = seen if seen < n_hist else n_hist  # hist.samples_in_history
        confident = n_eff > 1.0
        base = valid_fraction * (1.0 - 1.0 / n_eff) * (in_history / n_hist) if confident else 0.0
        fits = self._fits(nf, vals, n_valid, n_sl_valid) if self._k_fit else None
        pole_list = self._poles(vals, nf, confident, base, fits)
        p0 = self._k_pole_consts[0]
        bare, set_dict = object.__new__, object.__setattr__  # an instance without running the frozen __init__
        if confident:
            prom = vals[0]
            conf = base * prom / (prom + p0)
            conf = conf if conf > 0.0 else 0.0  # min(1.0, max(0.0, conf)), NaN and -0.0 alike
            conf = conf if conf < 1.0 else 1.0
        else:
            conf = 0.0
        result = bare(IdentificationResult)
        set_dict(
            result,
            "__dict__",
            {
                "poles": tuple(pole_list),
                "confidence": conf,
                "valid_fraction": valid_fraction,
                "samples_in_history": in_history,
                "effective_averages": n_eff,
            },
        )
        return result

    def _poles(self, vals: list[float], nf: int, confident: bool, base: float, fits: list[tuple[float, float] | None] | None) -> list[PoleEstimate]:
        """The step's poles from the kernel's prominences and pole rows (``vals``, read with one
        ``tolist``): the configured damping (VRM or FWHM first, a rational fit's where it gave one)
        and each pole's confidence, ``base`` times its prominence factor (module doc)."""
        p0, vrm_first, source = self._k_pole_consts
        pole_list = []
        bare, set_dict = object.__new__, object.__setattr__  # an instance without running the frozen __init__
        o = self._k_want + 4
        for p, prom in enumerate(vals[:nf]):
            f_peak, m_peak, zf, _ok, fn, zv = vals[o : o + 6]
            o += 6
            zeta_fwhm = None if zf != zf else zf  # NaN: undefined
            if zv != zv:
                zeta_vrm = fn_vrm = None
            else:
                zeta_vrm, fn_vrm = zv, fn
            if vrm_first:
                chosen = zeta_vrm if zeta_vrm is not None else zeta_fwhm
            else:
                chosen = zeta_fwhm if zeta_fwhm is not None else zeta_vrm
            zeta_fit = None
            fit = fits[p] if fits is not None else None
            if fit is not None:
                f_peak, zeta_fit = fit
                chosen = zeta_fit
            if confident:
                conf = base * prom / (prom + p0)
                conf = conf if conf < 1.0 else 1.0  # min(1.0, conf)
            else:
                conf = 0.0
            # PoleEstimate(...) field for field, without the frozen __init__'s eleven object.__setattr__
            pole = bare(PoleEstimate)
            set_dict(
                pole,
                "__dict__",
                {
                    "frequency_hz": f_peak,
                    "damping_ratio": chosen if chosen is not None else 0.0,
                    "damping_fwhm": zeta_fwhm,
                    "damping_vrm": zeta_vrm,
                    "natural_frequency_vrm_hz": fn_vrm,
                    "magnitude": m_peak,
                    "prominence_db": prom,
                    "source": source,
                    "damping_defined": chosen is not None,
                    "confidence": conf,
                    "damping_fit": zeta_fit,
                },
            )
            pole_list.append(pole)
        return pole_list

    def _solve_searched(self) -> None:
        """The searched spectrum on the slice when the compiled step starts at stage 3: the RLS's
        transfer functions (their mean or one ``H_ij``) on the valid bins, or the solver's."""
        c, sl, solver = self.cfg, self._sl, self._solver
        if self._first_stage < 3:
            return
        if self._rls is None:
            solver.solve_source(self._avg.state, c.peak_source, sl)
            return
        valid_sl = solver.mask(self._avg.state, sl)
        Hr = self._rls.H[:, sl]
        src_sl = self._rls_src[sl]
        if c.peak_source == "tot":
            np.mean(Hr, axis=0, out=src_sl)
        else:
            src_sl[...] = Hr[H_NAMES.index(c.peak_source)]
        src_sl *= valid_sl

    def _fits(self, nf: int, vals: list[float], n_valid: int, n_sl_valid: int) -> list[tuple[float, float] | None]:
        """``(f_n, ζ)`` of each peak's rational fit (``damping_method`` 'fit': the averaged FRF over
        ±``fit_band_hz``, :func:`.ratfit.fit_mode`; 'transient': the history's DFTs,
        :func:`.modal.fit_mode_transient`), None where it fails or lands outside the band."""
        c = self.cfg
        if c.estimate_on_smoothed:
            hd, fd, vd, all_valid = self._k_hs, self._f_range, self._k_vs, n_valid == self._k_n_range
        else:
            sl = self._sl
            hd, fd, vd, all_valid = self._src[sl], self._f_sl, self._solver.valid[sl], n_sl_valid == self._n_sl
        record = self._record_dft() if c.damping_method == "transient" else None
        fits: list[tuple[float, float] | None] = []
        o = self._k_want + 4
        for _ in range(nf):
            f_peak, ok = vals[o], vals[o + 3] != 0.0
            o += 6
            fit = None
            if c.damping_method == "fit" and ok:
                band = np.abs(fd - f_peak) <= c.fit_band_hz
                fit = fit_mode(fd[band], hd[band], None if all_valid else vd[band].astype(np.float64)[None, :])
            elif record is not None:
                f_all, X = record
                band = np.abs(f_all - f_peak) <= c.fit_band_hz
                fit = fit_mode_transient(f_all[band], X[:2, band], X[2:, band])
            fits.append(fit if fit is not None and abs(fit[0] - f_peak) <= c.fit_band_hz else None)
        return fits

    def _record_dft(self) -> tuple[NDArray[np.float64], NDArray[np.complex128]] | None:
        """The rectangular-window DFTs of the mean-removed history (4 rows: inputs, outputs) for
        damping_method 'transient'; None until the history is full."""
        hist = self.history
        if not hist.is_full:
            return None
        x = hist.view()
        X: NDArray[np.complex128] = np.fft.rfft(x - x.mean(axis=1, keepdims=True), axis=1)
        f: NDArray[np.float64] = np.fft.rfftfreq(hist.n, 1.0 / self.cfg.sample_rate_hz).astype(np.float64)
        return f, X

    # ----------------------------------------------------------- downloads
    def transfer_functions(self, smoothed: bool = True) -> TransferFunctionEstimate:
        """H11, H12, H21, H22 and H_tot (all bins) from the current averages (zeros before any step).

        Computed on demand (the step itself solves only what it searches).
        ``smoothed=False`` gives the averaged, unsmoothed estimates.
        """
        k = self._est.n_bins
        if self._avg.updates == 0:
            H = np.zeros((4, k), dtype=np.complex128)
            valid = np.zeros(k, dtype=bool)
        elif self._rls is not None:
            valid = self._solver.mask(self._avg.state).copy()
            H = self._rls.H * valid
        else:
            Hv, vv = self._solver.solve(self._avg.state)
            H, valid = Hv.copy(), vv.copy()
        mode = (self._solver.mode if self._rls is None and self._avg.updates else valid * np.uint8(2)).copy()
        if smoothed:
            sm = self._smoother
            H = sm.smooth(H)
            valid = sm.valid(valid)
            H *= valid
        mode *= valid
        htot = H.mean(axis=0)
        return TransferFunctionEstimate(
            freqs_hz=_readonly(self.freqs.copy()),
            h11=_readonly(H[0]),
            h12=_readonly(H[1]),
            h21=_readonly(H[2]),
            h22=_readonly(H[3]),
            htot=_readonly(htot),
            valid=_readonly(valid),
            mode=_readonly(mode.astype(np.uint8)),
        )

    def spectra(self, scaling: Literal["density", "spectrum", "raw"] = "density") -> dict[str, NDArray[np.complex128]]:
        """Averaged auto/cross spectra (P11 … P2y2, plus P21), scaled like scipy.signal.csd.

        ``'raw'`` returns the unscaled averaged ``conj(X)·Y`` (two-sided-style
        bins, no doubling). Averages are bias-corrected (divided by Σw).
        """
        mean = self._avg.mean()
        if scaling != "raw":
            mean = scale_spectra(mean, self._est.scale_factor(scaling), self._est.n)
        out = {name: mean[i].copy() for i, name in enumerate(SPECTRA_NAMES)}
        out["P21"] = np.conj(out["P12"])
        return out

    @property
    def effective_averages(self) -> float:
        """Independent averages the spectra hold (see :class:`.spectra.SpectralAverager`; with
        ``welch_segments`` > 1 each snapshot counts its segments)."""
        if self._seg_avgs > 1.0:
            est = self._est
            assert isinstance(est, SegmentedSpectralEstimator)
            return self._avg.segmented_effective_averages(est.segment_length, self._seg_avgs)
        return self._avg.effective_averages
