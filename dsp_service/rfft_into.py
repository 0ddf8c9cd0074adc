"""The identifier's real FFT into its own buffer, in the form that costs least per batch.

The reference is scipy's public ``scipy.fft.rfft(x, axis=-1)``. Called once per
batch, on caches the rest of the host has emptied since the last batch, its
dispatch (uarray), its Python argument handling and the copy of its fresh
result into the estimator's buffer cost far more than the transform itself:
at N = 2048 after a 2 ms pause, 89-101 µs against 42 µs for pocketfft's own
binding writing into the buffer (docs/dsp-performance.md, "The step inside
the service").

:func:`bind` therefore picks, once per buffer pair (when the identifier is
built), the first of these forms that gives the reference's bits on a probe
of the buffer's shape:

1. ``binding``: the pocketfft binding scipy.fft itself calls
   (``scipy.fft._pocketfft.pypocketfft.r2c``), writing into ``out``; not a
   public API, so it is looked up at import, probed, and passed over when it
   is missing, has another signature or gives other bits;
2. ``numpy``: ``numpy.fft.rfft(x, axis=-1, out=out)`` (public; numpy ≥ 2.0
   ships the same pocketfft);
3. ``scipy``: the reference itself, copied into ``out``.

Every form computes the same transform; the probe makes "the same bits" a
check on the installed versions, not an assumption, and the form in use is
named (:attr:`BoundRfft.form`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.fft
from numpy.typing import NDArray

try:  # the binding scipy.fft's rfft ends in (private: probed before every use, see bind)
    from scipy.fft._pocketfft.pypocketfft import r2c as _r2c
except ImportError:  # pragma: no cover - depends on the installed scipy
    _r2c = None

FORMS = ("binding", "numpy", "scipy")
"""The forms :func:`bind` tries, fastest first."""

PROBE_SEED = 20261207


def reference(x: NDArray[np.float64]) -> NDArray[np.complex128]:
    """``scipy.fft.rfft`` of every row of ``x``: the transform every form must reproduce bit for bit."""
    X: NDArray[np.complex128] = scipy.fft.rfft(x, axis=-1)
    return X


def _scipy_into(x: NDArray[np.float64], out: NDArray[np.complex128]) -> NDArray[np.complex128]:
    np.copyto(out, reference(x))
    return out


def _numpy_into(x: NDArray[np.float64], out: NDArray[np.complex128]) -> NDArray[np.complex128]:
    X: NDArray[np.complex128] = np.fft.rfft(x, axis=-1, out=out)
    return X


@dataclass(frozen=True)
class BoundRfft:
    """One form bound to its buffers: ``func(*args)`` writes the FFT of ``x``'s rows into ``out``."""

    form: str
    func: Callable[..., Any]
    args: tuple[Any, ...]

    def __call__(self) -> None:
        self.func(*self.args)


def _candidate(form: str, x: NDArray[np.float64], out: NDArray[np.complex128]) -> tuple[Callable[..., Any], tuple[Any, ...]] | None:
    if form == "binding":
        return None if _r2c is None else (_r2c, (x, (x.ndim - 1,), True, 0, out, 1))
    if form == "numpy":
        return _numpy_into, (x, out)
    return _scipy_into, (x, out)


def _same_bits(a: NDArray[np.complex128], b: NDArray[np.complex128]) -> bool:
    return a.shape == b.shape and bool(np.array_equal(a.view(np.float64), b.view(np.float64)))


def bind(x: NDArray[np.float64], out: NDArray[np.complex128], forms: tuple[str, ...] = FORMS) -> BoundRfft:
    """The first of ``forms`` that, run on a seeded probe in buffers shaped as ``x`` and ``out``,
    gives :func:`reference`'s bits, bound to ``x`` and ``out`` themselves (``scipy`` is always
    accepted: it is the reference). ``x``: C-contiguous float64 rows; ``out``: complex128, last axis
    ``N // 2 + 1``."""
    if x.dtype != np.float64 or out.dtype != np.complex128 or not x.flags.c_contiguous or out.shape != (*x.shape[:-1], x.shape[-1] // 2 + 1):
        raise ValueError(f"rfft_into.bind: float64 rows and a complex128 buffer of N // 2 + 1 bins expected, got {x.dtype}{x.shape} and {out.dtype}{out.shape}")
    probe = np.random.default_rng(PROBE_SEED).standard_normal(x.shape)
    want = reference(probe)
    for form in forms:
        got = np.empty_like(out)
        candidate = _candidate(form, probe, got)
        if candidate is None:
            continue
        func, args = candidate
        try:
            func(*args)
        except (TypeError, ValueError, RuntimeError):  # another signature in another version
            continue
        if _same_bits(got, want):
            bound = _candidate(form, x, out)
            assert bound is not None
            return BoundRfft(form, *bound)
    func, args = _scipy_into, (x, out)
    return BoundRfft("scipy", func, args)
