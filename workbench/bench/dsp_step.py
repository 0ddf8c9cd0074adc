"""Timing of one identification step against the bare numpy floor (thesis §2, C40 ≈ 100 ms).

:func:`bench_identifier` times, interleaved in the same run so both see the
same machine state:

* **step**: one :meth:`Identifier.step` (FFTs, averaging, solve, smoothing,
  peak search, FWHM and VRM damping) with the default configuration at FFT
  width ``n``, after appending a batch of 20 new samples (not timed), once
  30 half-overlapping snapshots have built up the averages;
* **floor**: the bare numpy minimum of the same FFT/spectra work, done the
  fastest plain-numpy way we know: one batched real FFT of the ``(4, n)``
  channels into a preallocated array, then the eight products
  ``conj(X_a)·X_b`` (P11, P12, P1y1, P1y2, P21, P22, P2y1, P2y2: ``conj(U_i)``
  times each of the four rows) as **one** broadcast multiply into a
  preallocated ``(2, 4, n/2+1)`` array. The ratios use this floor. Its FFT is
  the one the step uses (:func:`dsp_service.rfft_into.bind`: ``scipy.fft.rfft``'s bits, written
  into the buffer), so the ratio does not credit the step with a faster FFT. The slower forms of
  the same work, in the same blocks: ``floor_products_p50_us`` (the batched
  FFT and eight separate ``np.conj(X_a) * X_b``, the headline floor of this
  bench until it was found 20–45 % slower than the fused form; its ratio is
  ``ratio_products_p50``), ``floor_unbatched_p50_us`` (four separate FFT
  calls, eight separate products: the plainest reading of the work) and
  ``floor_numpy_p50_us`` (``np.fft.rfft`` itself and eight products).

Timings alternate in blocks of ten (step, then each floor) so all see the
same machine state.

:func:`bench_stages` splits the compiled step into its stages (each timed
alone on the same state, interleaved), :func:`bench_sizes` gives floor, step
and ratio for several N. Ratios are measured in one run on whatever machine
runs them: never a timed assertion.

The data are seeded random inputs, and outputs made of the inputs through
two lightly damped resonances plus noise, so the peak and damping stages do
real work (on pure noise they would often find no peak and return early).
"""

from __future__ import annotations

import time
from typing import TypedDict

import numpy as np
import scipy.signal

from dsp_service import rfft_into
from dsp_service.identifier import Identifier, IdentifierConfig
from dsp_service.spectra import rfft_rows

C40_STEP_US = 100_000.0  #: the C40's ≈ 100 ms per 2×2 iteration (§2)
_BATCH = 20
_WARMUP_SNAPSHOTS = 30
_BLOCK = 10
_PAIRS = ((0, 0), (1, 1), (0, 1), (1, 0), (0, 2), (0, 3), (1, 2), (1, 3))


class IdentifierBench(TypedDict):
    """One row of :func:`bench_identifier` (times in µs, ratios to the numpy floor of the same run)."""

    n: int
    repeats: int
    step_p50_us: float
    step_p99_us: float
    floor_p50_us: float
    floor_p99_us: float
    floor_products_p50_us: float
    floor_products_p99_us: float
    floor_unbatched_p50_us: float
    floor_numpy_p50_us: float
    ratio_p50: float
    ratio_p99: float
    ratio_products_p50: float
    c40_fraction: float
    poles_found: int


def _bench_data(n: int, repeats: int, fs: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    total = (_WARMUP_SNAPSHOTS + 1) * (n // 2) + (repeats + 10) * _BATCH
    u = rng.standard_normal((2, total))
    y = np.zeros_like(u)
    for fn, zeta, gain in ((3.6, 0.09, 1.0), (9.0, 0.05, 0.4)):
        wn = 2 * np.pi * fn
        b, a, _ = scipy.signal.cont2discrete(([gain * wn * wn], [1.0, 2 * zeta * wn, wn * wn]), 1.0 / fs, method="zoh")
        b = np.ravel(b)
        y[0] += scipy.signal.lfilter(b, a, u[0] + 0.5 * u[1])
        y[1] += scipy.signal.lfilter(b, a, 0.3 * u[0] + u[1])
    y += 0.01 * y.std() * rng.standard_normal(y.shape)
    return u, y


def _warmed(n: int, repeats: int) -> tuple[Identifier, np.ndarray, np.ndarray, int]:
    """An identifier at FFT width ``n`` after the warm-up snapshots, its data and the next position."""
    cfg = IdentifierConfig(fft_width=n)
    idf = Identifier(cfg)
    u, y = _bench_data(n, repeats, cfg.sample_rate_hz)
    half = n // 2
    idf.push(u[:, :half], y[:, :half])
    pos = half
    for _ in range(_WARMUP_SNAPSHOTS):
        idf.push(u[:, pos : pos + half], y[:, pos : pos + half])
        pos += half
        idf.step()
    return idf, u, y, pos


def bench_identifier(n: int = 2048, repeats: int = 200) -> IdentifierBench:
    """p50/p99 (µs) of one identification step and of the numpy floor, and their ratios.

    Returns keys: ``n``, ``repeats``, ``step_p50_us``, ``step_p99_us``,
    ``floor_p50_us``, ``floor_p99_us`` (the fused floor), ``floor_products_p50_us``,
    ``floor_products_p99_us``, ``floor_unbatched_p50_us``, ``floor_numpy_p50_us``,
    ``ratio_p50`` (step/floor), ``ratio_p99``, ``ratio_products_p50`` (step/products
    floor), ``c40_fraction`` (step p50 / 100 ms),
    ``poles_found`` (poles in the last step, to show the damping stages ran).
    """
    if repeats < 1:
        raise ValueError("repeats must be >= 1")
    # warm-up: 30 half-overlapping snapshots build independent averages, so the
    # timed steps find valid bins and peaks and run the damping estimators
    idf, u, y, pos = _warmed(n, repeats)
    data = np.vstack([u[:, :n], y[:, :n]])  # the floor's input (contents do not matter)
    rows = [np.ascontiguousarray(data[c]) for c in range(4)]
    perf = time.perf_counter
    step_t = np.empty(repeats)
    floor_t = np.empty(repeats)
    floor_prod_t = np.empty(repeats)
    floor4_t = np.empty(repeats)
    floor_np_t = np.empty(repeats)
    k = n // 2 + 1
    X_out = np.empty((4, k), dtype=np.complex128)
    fft = rfft_into.bind(data, X_out)  # the step's own form (its fft_form)
    fft_into, fft_args = fft.func, fft.args
    conj = np.empty((2, 1, k), dtype=np.complex128)
    fused = np.empty((2, 4, k), dtype=np.complex128)
    result = None
    # alternate small blocks of each kind, so both see the same machine state
    # (load, frequency) yet each runs with its own code and data warm
    for start in range(0, repeats, _BLOCK):
        stop = min(start + _BLOCK, repeats)
        for i in range(start, stop):
            idf.push(u[:, pos : pos + _BATCH], y[:, pos : pos + _BATCH])
            pos += _BATCH
            t0 = perf()
            result = idf.step()
            step_t[i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            fft_into(*fft_args)
            np.conjugate(X_out[:2, None], out=conj)
            np.multiply(conj, X_out, out=fused)  # conj(U_i)·X_j: all eight products at once
            floor_t[i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            X = rfft_rows(data)
            products = [np.conj(X[a]) * X[b] for a, b in _PAIRS]
            floor_prod_t[i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            Xs = [rfft_rows(r) for r in rows]
            products = [np.conj(Xs[a]) * Xs[b] for a, b in _PAIRS]
            floor4_t[i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            X = np.fft.rfft(data, axis=-1)
            products = [np.conj(X[a]) * X[b] for a, b in _PAIRS]
            floor_np_t[i] = perf() - t0
        del products
    s50, s99 = (float(v) * 1e6 for v in np.percentile(step_t, [50, 99]))
    f50, f99 = (float(v) * 1e6 for v in np.percentile(floor_t, [50, 99]))
    p50, p99 = (float(v) * 1e6 for v in np.percentile(floor_prod_t, [50, 99]))
    return {
        "n": int(n),
        "repeats": int(repeats),
        "step_p50_us": s50,
        "step_p99_us": s99,
        "floor_p50_us": f50,
        "floor_p99_us": f99,
        "floor_products_p50_us": p50,
        "floor_products_p99_us": p99,
        "floor_unbatched_p50_us": float(np.percentile(floor4_t, 50)) * 1e6,
        "floor_numpy_p50_us": float(np.percentile(floor_np_t, 50)) * 1e6,
        "ratio_p50": s50 / f50,
        "ratio_p99": s99 / f99,
        "ratio_products_p50": s50 / p50,
        "c40_fraction": s50 / C40_STEP_US,
        "poles_found": len(result.poles) if result is not None else 0,
    }


SIZES = (512, 1024, 2048, 4096, 8192)


def bench_sizes(sizes: tuple[int, ...] = SIZES, repeats: int = 200) -> list[IdentifierBench]:
    """:func:`bench_identifier` (compiled step and floor) at each FFT width."""
    return [bench_identifier(n, repeats) for n in sizes]


class StepPinger:
    """The step the DSP service makes per batch (a batch appended, then :meth:`Identifier.step`,
    both timed, as ``Interrupt.compute_time_s`` times them), stand-alone in this process: the
    zenoh item interleaves it with the service's round trips, so the in-service step is printed
    against it in the same run (``dsp_compute`` / ``dsp_step_standalone``). ``n``, ``batch``: the
    service's FFT width and batch size; the history is full before the first timed call."""

    name = "dsp_step_standalone"

    def __init__(self, n: int, batch: int, repeats: int) -> None:
        self.batch = batch
        self.idf, self.u, self.y, self.pos = _warmed(n, repeats * max(1, batch // _BATCH) + 2 * repeats)
        self.fft_form = str(self.idf._k.fft_form)

    def once(self) -> float:
        """One batch appended and one step, in seconds."""
        pos, b = self.pos, self.batch
        if pos + b > self.u.shape[1]:
            pos = self.idf.fft_width  # wrap over data already seen: the timing is what counts
        t0 = time.perf_counter()
        self.idf.push(self.u[:, pos : pos + b], self.y[:, pos : pos + b])
        self.idf.step()
        elapsed = time.perf_counter() - t0
        self.pos = pos + b
        return elapsed


def bench_stages(n: int = 2048, repeats: int = 200) -> dict[str, float]:
    """p50 (µs) of each stage of the compiled step at FFT width ``n``, and of the whole step.

    Stages, each timed alone on the identifier's current state (interleaved
    with the step, blocks of ten): ``detrend`` (the channel means, detrend and
    window), ``fft`` (the four real FFTs, one call), ``average`` (the seven spectra into the averages), ``solve``
    (the H_tot solve, dominant branch), ``smooth`` (Savitzky–Golay and
    validity over the search range), ``peaks`` (the peak search), ``poles``
    (refinement, FWHM, VRM); ``python`` is the step minus their sum (the
    Identifier's glue: result objects, confidences, call overhead); and the
    bench's ``floor``.
    """
    from dsp_service import kernel as K

    idf, u, y, pos = _warmed(n, repeats)
    c, avg, est, sv, sl, vrm = idf.cfg, idf._avg, idf._est, idf._solver, idf._sl, idf._vrm
    data = np.vstack([u[:, :n], y[:, :n]])
    names = ("step", "detrend", "fft", "average", "solve", "smooth", "peaks", "poles", "floor")
    t = {k: np.empty(repeats) for k in names}
    perf = time.perf_counter
    k = n // 2 + 1
    X_out = np.empty((4, k), dtype=np.complex128)
    fft = rfft_into.bind(data, X_out)
    conj = np.empty((2, 1, k), dtype=np.complex128)
    fused = np.empty((2, 4, k), dtype=np.complex128)
    for start in range(0, repeats, _BLOCK):
        stop = min(start + _BLOCK, repeats)
        for i in range(start, stop):
            idf.push(u[:, pos : pos + _BATCH], y[:, pos : pos + _BATCH])
            pos += _BATCH
            t0 = perf()
            idf.step()
            t["step"][i] = perf() - t0
        floor = float(idf._k.stats[3])
        n_valid, nf = int(idf._k.stats[1]), int(idf._k.stats[2])
        all_sl = int(idf._k.stats[0]) == sl.stop - sl.start
        state = avg.state.copy()
        hb = idf.history
        buf, head = hb._buf, hb._head
        for i in range(start, stop):
            t0 = perf()
            idf._k.detrend_ring(buf, head, est.means, est.window, est._tmp)
            t["detrend"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            idf._k.fft(*idf._k.fft_args)
            t["fft"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            K._accumulate(est.ffts.view(np.float64), 1.0, state.view(np.float64))
            t["average"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            K._solve_tot(avg.state, sl.start, sl.stop, floor, c.det_threshold, True, sv.source, sv.valid, sv.mode)
            t["solve"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            K._smooth(sv.source, sv.valid, idf._lo, idf._hi, idf._k.coef, idf._k.starts, idf._k.hs, idf._k.vs, idf._k.ia, idf._k.ib, all_sl)
            t["smooth"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            K._peaks(
                idf._k.hs,
                idf._k.vs,
                n_valid,
                idf._k.w,
                idf._w_lin is not None,
                idf._prom_ratio,
                c.max_peaks,
                idf._k.v,
                idf._k.order,
                idf._k.idx,
                idf._k.prom,
                idf._k.mag,
            )
            t["poles"][i] = 0.0
            t["peaks"][i] = perf() - t0
        src, vd = sv.source[sl], sv.valid[sl]
        for i in range(start, stop):
            t0 = perf()
            K.poles(
                src,
                vd,
                True,
                idf._f_sl,
                idf._lo - sl.start,
                idf._k.idx,
                nf,
                idf._relocate,
                c.fwhm_exact,
                idf._k.pinv,
                idf._refiner.r_max,
                vrm.m_max,
                vrm.band_factor,
                vrm.zeta_max,
                vrm._im_over_re_max,
                vrm.model == "viscous",
                idf._k.tri,
                idf._k.ntri,
                idf._k.mag[: src.size],
                idf._k.out,
            )
            t["poles"][i] = perf() - t0
        for i in range(start, stop):
            t0 = perf()
            fft.func(*fft.args)
            np.conjugate(X_out[:2, None], out=conj)
            np.multiply(conj, X_out, out=fused)
            t["floor"][i] = perf() - t0
    out = {k: float(np.percentile(v, 50)) * 1e6 for k, v in t.items()}
    out["python"] = out["step"] - sum(out[k] for k in _STAGES[:-2])
    return out


_STAGES = ("detrend", "fft", "average", "solve", "smooth", "peaks", "poles", "python", "step")


def format_report(rows: list[IdentifierBench], stages: dict[str, float]) -> str:
    """The size table and the stage breakdown as text (µs, ratios to the floor of the same run)."""
    lines = ["   N   floor us   step us  ratio  p99 ratio  products floor us  ratio"]
    for r in rows:
        lines.append(
            f"{r['n']:>5} {r['floor_p50_us']:>9.1f} {r['step_p50_us']:>9.1f} {r['ratio_p50']:>6.2f} {r['ratio_p99']:>10.2f}"
            f" {r['floor_products_p50_us']:>18.1f} {r['ratio_products_p50']:>6.2f}"
        )
    if not stages:
        return "\n".join(lines)
    f = stages["floor"]
    lines.append(f"stages at the bench's N (p50 us, / floor {f:.1f} us):")
    for k in _STAGES:
        lines.append(f"  {k:<8} {stages[k]:>8.1f}  {stages[k] / f:>5.2f}")
    return "\n".join(lines)
