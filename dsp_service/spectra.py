"""Windowed FFTs, auto/cross power spectra and their averaging (thesis §2.3, §5).

Conventions (identical to ``scipy.signal.csd``):

* every channel of the history is detrended by removing its mean
  (``detrend='constant'``), multiplied by the window and real-FFT'd;
* ``P_xy = conj(X) · Y``; so ``P_ij = E[U_i* U_j]`` and
  ``P_iyj = E[U_i* Y_j]`` exactly as in [2-10 … 2-24], with
  ``P21 = conj(P12)``;
* internally the spectra are *raw* (unscaled) products: the transfer-function
  solve is a ratio, so scaling cancels. :func:`scale_spectra` applies scipy's
  ``'density'`` (``1 / (fs Σw²)``) or ``'spectrum'`` (``1 / (Σw)²``) scaling and
  the one-sided doubling (every bin but DC and, for even ``N``, Nyquist) when
  a caller wants physical units.

Layout of a spectra array ``S`` (shape ``(7, K)``, ``K = N//2 + 1``): see the
row constants :data:`P11` … :data:`P2Y2`. P11 and P22 are stored complex with
zero imaginary part; P21 is not stored (it is ``conj(S[P12])``).

The mean is removed in the time domain before windowing, exactly as scipy
does (a constant input then becomes exactly, or to one rounding step,
zero, and is masked as silent downstream).

Averaging (applied to the *spectra*, never to the solved transfer functions,
[2-9] and §5): exponential ``S ← (1 − α) S + α S_new`` or the equal-weight
running mean (``α_k = 1/k``, i.e. Welch's average over segments).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
import scipy.fft
import scipy.signal
from numpy.typing import NDArray

from . import kernel
from .history import N_CHANNELS

#: Row indices of the spectra array.
P11, P12, P1Y1, P1Y2, P22, P2Y1, P2Y2 = range(7)
N_SPECTRA = 7
SPECTRA_NAMES: tuple[str, ...] = ("P11", "P12", "P1y1", "P1y2", "P22", "P2y1", "P2y2")

WindowSpec = str | tuple[str | float, ...]


def make_window(window: WindowSpec, n: int) -> NDArray[np.float64]:
    """Periodic (DFT-even) window of length ``n``, exactly as scipy.signal uses it."""
    return np.asarray(scipy.signal.get_window(window, n), dtype=np.float64)


def rfft_frequencies(n: int, sample_rate_hz: float) -> NDArray[np.float64]:
    """Bin centre frequencies (Hz) of a length-``n`` real FFT."""
    return np.asarray(np.fft.rfftfreq(n, d=1.0 / sample_rate_hz), dtype=np.float64)  # float64 already: no copy


def rfft_rows(x: NDArray[np.float64], out: NDArray[np.complex128] | None = None) -> NDArray[np.complex128]:
    """The real FFT of every row of ``x`` (``scipy.fft.rfft(x, axis=-1)``), copied into ``out`` if
    given. The FFT both the identifier and the bench's numpy floor use."""
    X: NDArray[np.complex128] = scipy.fft.rfft(x, axis=-1)
    if out is None:
        return X
    np.copyto(out, X)
    return out


class SpectralEstimator:
    """The window, frequency grid and buffers of one history snapshot's FFTs, computed once:
    the compiled step (:mod:`.kernel`) detrends, windows and averages into them; the FFTs are
    :func:`rfft_rows`'s."""

    def __init__(self, n: int, sample_rate_hz: float, window: WindowSpec = "hann") -> None:
        if n < 4:
            raise ValueError(f"FFT width must be >= 4, got {n}")
        self.n = int(n)
        self.sample_rate_hz = float(sample_rate_hz)
        self.window = make_window(window, self.n)
        self.n_bins = self.n // 2 + 1
        self.freqs = rfft_frequencies(self.n, self.sample_rate_hz)
        self.means = np.zeros(N_CHANNELS)
        """The last snapshot's channel means (detrend='constant')."""
        self._tmp = np.empty((N_CHANNELS, self.n))
        """The detrended, windowed channels of the last snapshot (the compiled step writes them)."""
        self.ffts = np.zeros((N_CHANNELS, self.n_bins), dtype=np.complex128)
        """The last snapshot's FFTs, rows u1, u2, y1, y2."""
        self.spectra = np.empty((N_SPECTRA, self.n_bins), dtype=np.complex128)

    # --------------------------------------------------------------- scaling
    def scale_factor(self, scaling: Literal["density", "spectrum"] = "density") -> float:
        """scipy's scale factor for raw ``conj(X)·Y`` products (before one-sided doubling)."""
        if scaling == "density":
            return 1.0 / (self.sample_rate_hz * float(np.sum(self.window**2)))
        if scaling == "spectrum":
            return 1.0 / float(np.sum(self.window)) ** 2
        raise ValueError(f"unknown scaling {scaling!r}")


def welch_equivalent_averages(segments: int, overlap_correlation: float = 0.1667) -> float:
    """Independent averages of ``segments`` half-overlapping windows (Welch 1967):
    ``S / (1 + 2 (1 − 1/S) ρ²)``, ``ρ`` = the window's correlation at 50 % overlap (Hann: 0.167)."""
    s = int(segments)
    return s / (1.0 + 2.0 * (1.0 - 1.0 / s) * overlap_correlation**2) if s > 1 else 1.0


class SegmentedSpectralEstimator(SpectralEstimator):
    """Welch within the history: the seven spectra averaged over ``segments`` half-overlapping windows.

    The history of ``N`` samples is cut into ``S`` segments of ``L = 2N/(S + 1)``
    samples overlapping by ``L/2``; each is detrended (its own mean, :func:`.kernel.row_mean`), windowed
    with an ``L``-point periodic window and FFT'd zero-padded to ``N`` (so the
    bin grid stays the thesis's, at a resolution of ``fs/L``); the spectra are
    the mean over segments of ``conj(X)·Y``. This is ``scipy.signal.csd(x, y,
    nperseg=L, noverlap=L/2, nfft=N, detrend='constant')`` up to its scaling
    (:meth:`scale_factor`). One snapshot then holds about
    :func:`welch_equivalent_averages` independent averages instead of one,
    which is what the exponential average of 98 %-overlapping snapshots
    lacks (it holds ≈ 1.35 at N 2048, α 0.1, l 20).

    :attr:`ffts` holds the last segment's FFTs only (not usable by the per-bin RLS).
    """

    def __init__(self, n: int, sample_rate_hz: float, window: WindowSpec = "hann", segments: int = 3) -> None:
        super().__init__(n, sample_rate_hz, window)
        s = int(segments)
        if s < 2:
            raise ValueError(f"segments must be >= 2, got {segments}")
        seg = (2 * self.n) // (s + 1)
        if seg < 8 or seg % 2:
            raise ValueError(f"{s} segments of an N = {n} history are {seg} samples: too short or odd")
        self.segment_length = seg
        self.hop = seg // 2
        self.window = make_window(window, seg)
        self._starts = [k * self.hop for k in range(s)]
        self._seg = np.zeros((s, N_CHANNELS, self.n))  # zero-padded, windowed segments
        k = self.n_bins
        self._segX = np.empty((s, N_CHANNELS, k), dtype=np.complex128)

    def snapshot(self, history: NDArray[np.float64], scale: float = 1.0) -> NDArray[np.complex128]:
        """Mean over the segments of the raw spectra ``(7, K)`` of one ``(4, N)`` history, times ``scale``."""
        seg, L = self._seg, self.segment_length
        for i, a in enumerate(self._starts):
            x = history[:, a : a + L]
            dst = seg[i, :, :L]
            for r in range(N_CHANNELS):  # detrend='constant' by the step's own channel mean
                np.subtract(x[r], kernel.row_mean(x[r]), out=dst[r])
            dst *= self.window
        X = rfft_rows(seg.reshape(-1, self.n), self._segX.reshape(-1, self.n_bins)).reshape(self._segX.shape)
        U = np.conj(X[:, 0:2])  # (S, 2, K)
        sp = self.spectra
        sp[P11] = np.mean(U[:, 0] * X[:, 0], axis=0)
        sp[P12] = np.mean(U[:, 0] * X[:, 1], axis=0)
        sp[P1Y1] = np.mean(U[:, 0] * X[:, 2], axis=0)
        sp[P1Y2] = np.mean(U[:, 0] * X[:, 3], axis=0)
        sp[P22] = np.mean(U[:, 1] * X[:, 1], axis=0)
        sp[P2Y1] = np.mean(U[:, 1] * X[:, 2], axis=0)
        sp[P2Y2] = np.mean(U[:, 1] * X[:, 3], axis=0)
        if scale != 1.0:
            sp *= scale
        self.ffts[...] = X[-1]
        return sp


def scale_spectra(
    raw: NDArray[np.complex128],
    factor: float,
    n: int,
    onesided: bool = True,
) -> NDArray[np.complex128]:
    """Scaled copy of raw spectra (``(..., K)``), with scipy's one-sided doubling."""
    out = raw * factor
    if onesided:
        if n % 2:
            out[..., 1:] *= 2.0
        else:
            out[..., 1:-1] *= 2.0
    return out


class SpectralAverager:
    """Averages raw spectra across C40 iterations (applied before the solve).

    ``method='exponential'``: ``S ← (1 − α) S + α S_new`` [2-9].
    ``method='linear'``: the equal-weight mean of all snapshots since the
    reset (``α_k = 1/k``), which is what Welch's method (``scipy.signal.csd``)
    does over segments.

    Implementation (same result, fewer passes over memory): the state is kept
    *unnormalised*, ``S' = Σ_i c_i S_i`` with ``c_i = (1 − α)^{−i}`` (or 1 for
    'linear'), so an update is a single ``S' += c_k S_k`` and the weight
    ``c_k`` is folded into the snapshot's ``conj(U)`` rows by the caller
    (:meth:`next_weight` then :meth:`add`). The true average is
    ``S' / Σc`` (:meth:`mean`); the transfer-function solve is a ratio, so it
    uses ``S'`` directly. When ``c`` grows past 1e100 everything is rescaled.

    Effective number of averages (documented, used for the confidence):
    the Kish effective sample size of the weights, ``(Σc)² / Σc²`` — for
    exponential averaging it tends to ``(2 − α)/α`` — capped for overlapping
    snapshots: with ``l̄`` new samples per iteration (weighted mean) the
    averaged data span ``N + l̄ (n_kish − 1)`` samples, which hold about
    ``1 + 2 l̄ (n_kish − 1) / N`` independent half-overlapping Hann windows:
    ``effective_averages = min(n_kish, 1 + 2 l̄ (n_kish − 1) / N)``.
    """

    _RESCALE_AT = 1e100

    def __init__(
        self,
        shape: tuple[int, ...],
        n: int,
        method: Literal["exponential", "linear"] = "exponential",
        alpha: float = 0.1,
    ) -> None:
        if method not in ("exponential", "linear"):
            raise ValueError(f"unknown averaging method {method!r}")
        if not 0.0 < alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {alpha}")
        self.method = method
        self.alpha = float(alpha)
        self.n = int(n)
        self.state = np.zeros(shape, dtype=np.complex128)
        self.reset()

    def reset(self) -> None:
        """Forget everything (spectra and weight bookkeeping)."""
        self.state.fill(0.0)
        self.updates = 0
        self._c = 1.0  # weight of the next snapshot
        self._sum_c = 0.0  # Σ c
        self._sum_c2 = 0.0  # Σ c²
        self._sum_cl = 0.0  # Σ c·l  (new samples per iteration)

    def next_weight(self) -> float:
        """Weight ``c_k`` for the coming snapshot (rescales the state if it grew too large)."""
        if self.updates == 0:
            self._c = 1.0
        elif self.method == "exponential":
            c = self._c / (1.0 - self.alpha) if self.alpha < 1.0 else self._c
            if self.alpha == 1.0:  # no memory at all
                self.state.fill(0.0)
                self._sum_c = self._sum_c2 = self._sum_cl = 0.0
            elif c > self._RESCALE_AT:
                eps = 1.0 / self._c
                self.state *= eps
                self._sum_c *= eps
                self._sum_c2 *= eps * eps
                self._sum_cl *= eps
                c *= eps
            self._c = c
        return self._c

    def add(self, weighted: NDArray[np.complex128], new_samples: int) -> None:
        """Accumulate a snapshot already multiplied by :meth:`next_weight`."""
        self.state += weighted
        self._account(self._c, new_samples)

    def _account(self, c: float, new_samples: int) -> None:
        """The bookkeeping of one snapshot of weight ``c`` (its state already added)."""
        self.updates += 1
        self._sum_c += c
        self._sum_c2 += c * c
        self._sum_cl += c * float(new_samples)

    def take(self, new_samples: int) -> float:
        """:meth:`next_weight`, then :meth:`add`'s bookkeeping, in one call: the weight of a snapshot the
        caller adds to :attr:`state` itself (the compiled step)."""
        c = self.next_weight()
        self._account(c, new_samples)
        return c

    def update(self, new: NDArray[np.complex128], new_samples: int) -> None:
        """Blend in one (unweighted) snapshot; ``new_samples`` = samples appended since the last one."""
        c = self.next_weight()
        self.add(new * c, new_samples)

    def mean(self) -> NDArray[np.complex128]:
        """The average ``S' / Σc`` (zeros before the first update)."""
        if self._sum_c == 0.0:
            return np.zeros_like(self.state)
        return self.state / self._sum_c

    @property
    def kish_averages(self) -> float:
        """``(Σc)² / Σc²``: averages if every snapshot were independent."""
        return self._sum_c * self._sum_c / self._sum_c2 if self._sum_c2 > 0.0 else 0.0

    def segmented_effective_averages(self, segment_length: int, per_snapshot: float) -> float:
        """:attr:`effective_averages` for snapshots that each average ``per_snapshot`` segments of
        ``segment_length`` samples: ``min(n_kish · K, K + 2 l̄ (n_kish − 1) / L)``."""
        kish = self.kish_averages
        if kish == 0.0:
            return 0.0
        mean_new = self._sum_cl / self._sum_c
        return float(min(kish * per_snapshot, per_snapshot + 2.0 * mean_new * (kish - 1.0) / segment_length))

    @property
    def effective_averages(self) -> float:
        """Kish count capped by the independent data the overlapping snapshots hold."""
        kish = self.kish_averages
        if kish == 0.0:
            return 0.0
        mean_new = self._sum_cl / self._sum_c
        span_limited = 1.0 + 2.0 * mean_new * (kish - 1.0) / self.n
        return float(min(kish, span_limited))
