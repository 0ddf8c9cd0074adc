"""The identifier's compiled step prepared for one configuration (:class:`CompiledStep`).

Everything :func:`.kernel.step_packed` takes but the snapshot and its weight depends only on the
configuration: the smoothing rows over the search range, the log weights, the frequency grids, the
refinement pseudo-inverses and the VRM triplets, its scalars, scratch and outputs. They are packed
once here into the kernel's three flat arrays (:func:`.kernel.pack_arguments`) and the compiled
overloads resolved, so a step makes one call of 11 arguments with no per-call type resolution.
The named attributes are views into the packed arrays: what the Python side reads after a call.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from . import kernel, rfft_into
from .identifier_config import IdentifierConfig
from .modal import PeakRefiner, VrmEstimator, log_weights
from .smoothing import FrequencySmoother
from .spectra import SpectralAverager, SpectralEstimator

_EST_MARGIN_BINS = 32  #: bins solved beyond the search range for FWHM/VRM near its edges


class SearchRange(NamedTuple):
    """The bins the step searches and solves (:func:`search_range`)."""

    lo: int  #: first bin of the peak search
    hi: int  #: one past its last
    sl: slice  #: the bins solved each step: the search range and a margin
    f_sl: NDArray[np.float64]  #: their frequencies
    f_range: NDArray[np.float64]  #: the search range's frequencies
    w_lin: NDArray[np.float64] | None  #: the log weighting as a linear factor (None: off)
    prom_ratio: float  #: the minimum prominence as a ratio
    relocate: int  #: bins a peak may move to the raw spectrum's maximum


def search_range(c: IdentifierConfig, freqs: NDArray[np.float64], half: int) -> SearchRange:
    """The search range of ``c`` on the bins ``freqs`` with a smoothing window of half-width ``half``:
    the bins solved each step are the search range plus a margin for the smoothing windows and the
    damping estimators (FWHM crossings, VRM band)."""
    k = freqs.size
    df = c.sample_rate_hz / c.fft_width
    lo = max(1, math.ceil(c.search_min_hz / df - 1e-9))
    hi = min(k, math.floor(c.search_max_hz / df + 1e-9) + 1)
    f_range = freqs[lo:hi]
    f_ref = max(c.search_min_hz, df)
    # the peak search ranks |H|·w on a linear scale (the same order and the same
    # peaks as 20 log10|H| + 20 log10 w in dB); prominences become ratios
    w_lin = log_weights(f_range, f_ref, c.log_weight_exponent) if c.log_weighting else None
    margin = max(2 * half + 1, _EST_MARGIN_BINS)
    sl = slice(max(0, lo - margin), min(k, hi + margin))
    return SearchRange(lo, hi, sl, freqs[sl], f_range, w_lin, 10.0 ** (c.min_peak_prominence_db / 20.0), max(1, half // 2))


class CompiledStep:
    """The packed arguments and resolved overloads of the identifier's compiled step (module doc).

    ``src``, ``valid``, ``mode``: the searched spectrum, its mask and per-bin solve mode (the solver's
    buffers, or the RLS's); ``first_stage``: where :func:`.kernel.step_packed` starts (1 averages the
    snapshot's FFTs and solves ``H_tot``; 2 solves ``H_tot`` of averages made before; 3 searches a
    spectrum solved before); ``lo``, ``hi``: the search range; ``sl``: the bins solved each step."""

    def __init__(
        self,
        c: IdentifierConfig,
        est: SpectralEstimator,
        avg: SpectralAverager,
        ring: NDArray[np.float64],
        spectrum: tuple[NDArray[np.complex128], NDArray[np.bool_], NDArray[np.uint8]],
        first_stage: int,
        search: SearchRange,
        smoother: FrequencySmoother,
        refiner: PeakRefiner,
        vrm: VrmEstimator,
    ) -> None:
        lo, hi, sl, f_sl, f_range, w_lin, prom_ratio, relocate = search
        n_range, k, n_sl = hi - lo, est.n_bins, sl.stop - sl.start
        coef, starts, ia, ib = smoother.rows(lo, hi)
        self.ffts_f = est.ffts.view(np.float64)  # (re, im) float view for the averaging
        self.zeros_f = np.zeros_like(self.ffts_f)
        self.hs = np.empty(n_range, dtype=np.complex128)  #: the smoothed spectrum over the search range
        self.vs = np.empty(n_range, dtype=bool)  #: its validity
        self.ia, self.ib = ia, ib
        pinv, tri, n_tri = refiner.pinv, vrm.tri, vrm.n_tri
        kernel.warm_up()
        ip = np.zeros(kernel.N_IP, dtype=np.intp)
        for i, value in (
            (kernel.IP_BINS, k),
            (kernel.IP_S0, sl.start),
            (kernel.IP_S1, sl.stop),
            (kernel.IP_DOMINANT, c.collinear == "dominant"),
            (kernel.IP_LO, lo),
            (kernel.IP_HI, hi),
            (kernel.IP_IA, ia),
            (kernel.IP_IB, ib),
            (kernel.IP_WEIGHTED, w_lin is not None),
            (kernel.IP_WANT, c.max_peaks),
            (kernel.IP_FIRST, first_stage),
            (kernel.IP_ON_SMOOTHED, c.estimate_on_smoothed),
            (kernel.IP_RELOCATE, relocate),
            (kernel.IP_FWHM_EXACT, c.fwhm_exact),
            (kernel.IP_R_MAX, refiner.r_max),
            (kernel.IP_M_MAX, vrm.m_max),
            (kernel.IP_VISCOUS, vrm.model == "viscous"),
        ):
            ip[i] = int(value)
        fp = np.zeros(kernel.N_FP)
        fp[kernel.FP_POWER_FLOOR], fp[kernel.FP_DET], fp[kernel.FP_RATIO] = c.power_floor, c.det_threshold, prom_ratio
        fp[kernel.FP_BAND], fp[kernel.FP_ZETA_MAX], fp[kernel.FP_C_MAX] = vrm.band_factor, vrm.zeta_max, vrm._im_over_re_max
        w = w_lin if w_lin is not None else np.ones(n_range)
        fk, ik, fw, views = kernel.pack_arguments(fp, ip, coef, w, f_sl, f_range, pinv, starts, tri, n_tri, max(n_sl, n_range))
        self._views(views)
        self.args = (fk, ik, fw, avg.state, *spectrum, self.hs, self.vs)
        self._resolve(est, avg, ring)
        # what a step reads of the configuration (fixed until the next build; set_alpha changes none of it)
        self.early = not c.wait_for_full_history
        self.want, self.n_range = c.max_peaks, n_range
        self.pole_consts = (c.confidence_prominence_db, c.damping_method != "fwhm", c.peak_source)
        self.fit = c.damping_method in ("fit", "transient")

    def _views(self, views: dict[str, Any]) -> None:
        """The packed arrays by name (views into the kernel's flat arrays; module doc)."""
        self.coef, self.w, self.pinv = views["coef"], views["w_lin"], views["pinv"]
        self.starts, self.tri, self.ntri, self.order = views["starts"], views["tri"], views["n_tri"], views["order"]
        self.idx, self.prom, self.stats, self.mag, self.out = views["idx"], views["prom"], views["stats"], views["mag"], views["out"]
        self.v = views["v"]
        self.tail = views["tail"]  #: prominences, the four counters and the pole rows, read with one tolist

    def _resolve(self, est: SpectralEstimator, avg: SpectralAverager, ring: NDArray[np.float64]) -> None:
        """The compiled overloads of the step, the detrend and the averaging alone, each resolved once
        on arguments that change nothing (no snapshot: weight 0 on a zero state)."""
        self.call = kernel.compiled_entry(kernel.step_packed, (self.zeros_f, 0.0, *self.args))
        fft = rfft_into.bind(est._tmp, est.ffts)  # the snapshot's FFT into the estimator's buffer (module doc there)
        self.fft, self.fft_args, self.fft_form = fft.func, fft.args, fft.form
        self.dtr_args = (est.means, est.window, est._tmp)
        self.detrend_ring = kernel.compiled_entry(kernel.detrend_window_ring, (ring, 0, *self.dtr_args))
        self.state_f = avg.state.view(np.float64)
        # the averaging alone (settings whose solve runs before the compiled search)
        self.accumulate = kernel.compiled_entry(kernel._accumulate, (self.zeros_f, 0.0, self.state_f))
