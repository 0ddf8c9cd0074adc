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
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from . import downloads
from .arx import RecursiveArx
from .arx_regime_bank import RegimeBankState
from .compiled_step import CompiledStep, search_range
from .history import HistoryBuffer
from .identifier_arx import ArxPoles
from .identifier_config import (
    IdentificationResult,
    IdentifierConfig,
    PoleEstimate,
    TransferFunctionEstimate,
    arx_config,
    arx_rate_and_band,
)
from .mimo import H_NAMES, MimoSolver, ScalarRLS, VectorRLS
from .modal import (
    PeakRefiner,
    VrmEstimator,
)
from .pole_readout import pole_estimates, rational_fits, record_dft
from .smoothing import FrequencySmoother
from .spectra import (
    SegmentedSpectralEstimator,
    SpectralAverager,
    SpectralEstimator,
    welch_equivalent_averages,
)

__all__ = [
    "IdentificationResult",
    "Identifier",
    "IdentifierConfig",
    "PoleEstimate",
    "TransferFunctionEstimate",
    "arx_config",
    "arx_rate_and_band",
]

log = logging.getLogger(__name__)

_TINY = float(np.finfo(np.float64).tiny)


class Identifier:
    """Pure, synchronous 2-input 2-output on-line identifier (the emulated C40)."""

    def __init__(self, cfg: IdentifierConfig | None = None) -> None:
        self.cfg = cfg if cfg is not None else IdentifierConfig()
        self._arx_seed: RegimeBankState | None = None
        self._arx: ArxPoles | None = None
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
        search = search_range(c, self.freqs, self._smoother.half)
        self._lo, self._hi, self._sl, self._f_sl, self._f_range, self._w_lin, self._prom_ratio, self._relocate = search
        self._n_sl = self._sl.stop - self._sl.start
        self._vrm = VrmEstimator(c.vrm_points_per_side, c.vrm_band_factor, model=c.vrm_model)
        self._refiner = PeakRefiner()
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
        spectrum = (self._src, self._solver.valid, self._solver.mode)
        self._k = CompiledStep(c, self._est, self._avg, self.history._buf, spectrum, self._first_stage, search, self._smoother, self._refiner, self._vrm)
        self._pending = 0
        self._arx = ArxPoles(c, carried, self._arx_seed) if c.method == "arx" else None

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
            self._arx.push(inputs, outputs)

    @property
    def samples_in_history(self) -> int:
        return self.history.samples_in_history

    # ----------------------------------------------------------------- step
    def step(self) -> IdentificationResult:
        """One iteration: the ETFE's (below), with ``method='arx'`` the ARX model's poles instead."""
        result = self._step_etfe()
        return result if self._arx is None else self._arx.result(result)

    @property
    def arx(self) -> RecursiveArx | None:
        """The recursive ARX model (``method='arx'``), else None."""
        return self._arx.model if self._arx is not None else None

    def seed_arx_bank(self, state: RegimeBankState) -> None:
        """Seed the ARX model's regime bank with another run's (:meth:`RecursiveArx.load_bank`, before the first
        batch), and again whenever the model is rebuilt; ``ValueError`` without an ARX model with a bank, or for
        a bank that does not fit it (the model unchanged)."""
        if self._arx is None:
            raise ValueError("a regime bank needs identifier 'arx'")
        self._arx.model.load_bank(state)
        self._arx_seed = state

    def arx_bank_state(self) -> RegimeBankState | None:
        """The ARX model's regime bank as it stands (to carry into another run), None without an ARX model,
        without a bank or before its first batch with signal."""
        return self._arx.bank_state() if self._arx is not None else None

    def _step_etfe(self) -> IdentificationResult:
        """One C40 iteration on the current history (module doc): one compiled call
        (:func:`.kernel.step_packed`, :meth:`_run_kernel`), then the result (:meth:`_result`).

        With an empty history (nothing pushed since the last reset), or with
        ``wait_for_full_history`` before N samples have arrived, nothing is
        averaged; until the first average an empty result is returned.
        Everything the call needs but the snapshot and its weight is fixed until the next
        :meth:`_build` (:class:`.compiled_step.CompiledStep`); the kernel's counters,
        prominences and poles are read with one ``tolist`` (its ``tail``)."""
        hist = self.history
        seen, n_hist = hist._seen, hist._n  # hist.samples_seen, hist.n (the properties, without their calls)
        if not self._run_kernel(seen > 0 and (seen >= n_hist or self._k.early)):
            return IdentificationResult((), 0.0, 0.0, min(seen, n_hist), 0.0)
        return self._result(self._k.tail.tolist())

    def _run_kernel(self, snapshot: bool) -> bool:
        """The compiled call from the stage the configuration needs, with the history's snapshot
        (``snapshot``) or on the averages as they are; the segmented spectra, the RLS and the
        solves other than the corrected ``H_tot`` made before it here. False (no call) before the first average."""
        ks, avg, first = self._k, self._avg, self._first_stage
        if not snapshot:
            if avg.updates == 0:
                return False
            self._solve_searched()
            ks.call(ks.zeros_f, 0.0, *ks.args)
            return True
        hist = self.history
        if self._seg_avgs == 1.0:  # one window per snapshot: the compiled detrend and averaging
            weight = avg.take(self._pending)  # next_weight and the bookkeeping: the kernel adds the snapshot
            self._pending = 0
            # detrend='constant', then window (scipy.signal.csd's order)
            ks.detrend_ring(hist._buf, hist._head, *ks.dtr_args)
            ks.fft(*ks.fft_args)  # rfft_into.bind's form: scipy.fft.rfft's bits
            if first == 1:
                ks.call(ks.ffts_f, weight, *ks.args)
                return True
            ks.accumulate(ks.ffts_f, weight, ks.state_f)
            if self._rls is not None:
                self._rls.update(self._est.ffts)
        else:  # Welch segments within the history
            est = self._est
            assert isinstance(est, SegmentedSpectralEstimator)
            weight = avg.next_weight()
            avg.add(est.snapshot(hist.view(), weight), self._pending)
            self._pending = 0
        self._solve_searched()
        ks.call(ks.zeros_f, 0.0, *ks.args)
        return True

    def _result(self, vals: list[float]) -> IdentificationResult:
        """The step's result from the kernel's ``tail`` (``vals``: prominences[want], stats[4],
        poles[want × 6]): the counters, the confidences (module doc), the poles."""
        ks, hist = self._k, self.history
        seen, n_hist = hist._seen, hist._n
        want = ks.want
        f_sl_valid, f_valid, f_nf = vals[want : want + 3]
        n_sl_valid = int(f_sl_valid)
        n_valid, nf = int(f_valid), int(f_nf)
        n_range = ks.n_range
        if nf == 0:
            return IdentificationResult((), 0.0, n_valid / n_range, hist.samples_in_history, float(self.effective_averages))
        # the confidences, computed before the poles are made
        n_eff = self.effective_averages
        valid_fraction = n_valid / n_range
        in_history = seen if seen < n_hist else n_hist  # hist.samples_in_history
        confident = n_eff > 1.0
        base = valid_fraction * (1.0 - 1.0 / n_eff) * (in_history / n_hist) if confident else 0.0
        fits = self._fits(nf, vals, n_valid, n_sl_valid) if ks.fit else None
        pole_list = pole_estimates(vals, nf, ks.want, ks.pole_consts, confident, base, fits)
        p0 = ks.pole_consts[0]
        if confident:
            prom = vals[0]
            conf = base * prom / (prom + p0)
            conf = conf if conf > 0.0 else 0.0  # min(1.0, max(0.0, conf)), NaN and -0.0 alike
            conf = conf if conf < 1.0 else 1.0
        else:
            conf = 0.0
        result = object.__new__(IdentificationResult)  # an instance without running the frozen __init__
        fields = {
            "poles": tuple(pole_list),
            "confidence": conf,
            "valid_fraction": valid_fraction,
            "samples_in_history": in_history,
            "effective_averages": n_eff,
        }
        object.__setattr__(result, "__dict__", fields)
        return result

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
        """``(f_n, ζ)`` of each peak's rational fit (:func:`.pole_readout.rational_fits`) on the spectrum the
        poles were estimated on, or on the history's DFTs (``damping_method`` 'transient')."""
        c, ks = self.cfg, self._k
        if c.estimate_on_smoothed:
            hd, fd, vd, all_valid = ks.hs, self._f_range, ks.vs, n_valid == ks.n_range
        else:
            sl = self._sl
            hd, fd, vd, all_valid = self._src[sl], self._f_sl, self._solver.valid[sl], n_sl_valid == self._n_sl
        record = record_dft(self.history, c.sample_rate_hz) if c.damping_method == "transient" else None
        return rational_fits(c, [(vals[o], vals[o + 3] != 0.0) for o in range(ks.want + 4, ks.want + 4 + 6 * nf, 6)], (hd, fd, vd, all_valid), record)

    # ----------------------------------------------------------- downloads
    def transfer_functions(self, smoothed: bool = True) -> TransferFunctionEstimate:
        """H11, H12, H21, H22 and H_tot (all bins) from the current averages (zeros before any step;
        :func:`.downloads.transfer_functions`). ``smoothed=False`` gives the averaged, unsmoothed estimates."""
        return downloads.transfer_functions(self.freqs, self._avg, self._solver, self._rls, self._smoother if smoothed else None)

    def spectra(self, scaling: Literal["density", "spectrum", "raw"] = "density") -> dict[str, NDArray[np.complex128]]:
        """Averaged auto/cross spectra (P11 … P2y2, plus P21), scaled like scipy.signal.csd
        (:func:`.downloads.averaged_spectra`)."""
        return downloads.averaged_spectra(self._avg, self._est, scaling)

    @property
    def effective_averages(self) -> float:
        """Independent averages the spectra hold (see :class:`.spectra.SpectralAverager`; with
        ``welch_segments`` > 1 each snapshot counts its segments)."""
        if self._seg_avgs > 1.0:
            est = self._est
            assert isinstance(est, SegmentedSpectralEstimator)
            return self._avg.segmented_effective_averages(est.segment_length, self._seg_avgs)
        return self._avg.effective_averages
