"""The identifier's poles from its compiled step's output (:func:`pole_estimates`) and the rational
fits of their damping (:func:`rational_fits`: ``damping_method`` 'fit' or 'transient')."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .history import HistoryBuffer
from .identifier_config import IdentifierConfig, PoleEstimate
from .modal import fit_mode_transient
from .ratfit import fit_mode


def pole_estimates(
    vals: list[float],
    nf: int,
    want: int,
    pole_consts: tuple[float, bool, str],
    confident: bool,
    base: float,
    fits: list[tuple[float, float] | None] | None,
) -> list[PoleEstimate]:
    """The step's poles from the kernel's prominences and pole rows (``vals``, read with one
    ``tolist``; ``want`` peaks at most, ``nf`` found): the configured damping (VRM or FWHM first, a rational fit's where it gave one)
    and each pole's confidence, ``base`` times its prominence factor (:mod:`.identifier`'s module doc); ``pole_consts``: the prominence
    of confidence 0.5, VRM first, the searched spectrum's name."""
    p0, vrm_first, source = pole_consts
    pole_list = []
    bare, set_dict = object.__new__, object.__setattr__  # an instance without running the frozen __init__
    o = want + 4
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


def rational_fits(
    c: IdentifierConfig,
    peaks: list[tuple[float, bool]],
    spectrum: tuple[NDArray[np.complex128], NDArray[np.float64], NDArray[np.bool_], bool],
    record: tuple[NDArray[np.float64], NDArray[np.complex128]] | None,
) -> list[tuple[float, float] | None]:
    """``(f_n, ζ)`` of each peak's rational fit, for ``peaks`` (its frequency, whether its bin is valid):
    ``damping_method`` 'fit': the averaged FRF ``spectrum`` (values, frequencies, validity, all valid)
    over ±``fit_band_hz`` (:func:`.ratfit.fit_mode`); 'transient': the history's DFTs ``record``
    (:func:`record_dft`, :func:`.modal.fit_mode_transient`). None where it fails or lands outside the band."""
    hd, fd, vd, all_valid = spectrum
    fits: list[tuple[float, float] | None] = []
    for f_peak, ok in peaks:
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


def record_dft(hist: HistoryBuffer, sample_rate_hz: float) -> tuple[NDArray[np.float64], NDArray[np.complex128]] | None:
    """The rectangular-window DFTs of the mean-removed history (4 rows: inputs, outputs) for
    damping_method 'transient'; None until the history is full."""
    if not hist.is_full:
        return None
    x = hist.view()
    X: NDArray[np.complex128] = np.fft.rfft(x - x.mean(axis=1, keepdims=True), axis=1)
    f: NDArray[np.float64] = np.fft.rfftfreq(hist.n, 1.0 / sample_rate_hz).astype(np.float64)
    return f, X
