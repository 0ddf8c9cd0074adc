"""What the identifier's board downloads on request: the transfer functions of all bins and the
averaged spectra, computed from the current averages (the step itself solves only what it searches)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import NDArray

from .identifier_config import TransferFunctionEstimate, readonly
from .mimo import MimoSolver, ScalarRLS, VectorRLS
from .smoothing import FrequencySmoother
from .spectra import SPECTRA_NAMES, SpectralAverager, SpectralEstimator, scale_spectra


def transfer_functions(
    freqs: NDArray[np.float64],
    avg: SpectralAverager,
    solver: MimoSolver,
    rls: ScalarRLS | VectorRLS | None,
    smoother: FrequencySmoother | None,
) -> TransferFunctionEstimate:
    """H11, H12, H21, H22 and H_tot on every bin of ``freqs`` from the averages ``avg`` (zeros before
    any): solved by ``solver`` [2-21 … 2-28] or, with ``rls``, the RLS's on the solver's mask; smoothed
    by ``smoother`` (§2.4.1; None: the averaged, unsmoothed estimates), its validity applied; per bin
    the solve used (``mode``); ``H_tot`` the mean of the four."""
    k = freqs.size
    if avg.updates == 0:
        H = np.zeros((4, k), dtype=np.complex128)
        valid = np.zeros(k, dtype=bool)
    elif rls is not None:
        valid = solver.mask(avg.state).copy()
        H = rls.H * valid
    else:
        Hv, vv = solver.solve(avg.state)
        H, valid = Hv.copy(), vv.copy()
    mode = (solver.mode if rls is None and avg.updates else valid * np.uint8(2)).copy()
    if smoother is not None:
        H = smoother.smooth(H)
        valid = smoother.valid(valid)
        H *= valid
    mode *= valid
    htot = H.mean(axis=0)
    return TransferFunctionEstimate(
        freqs_hz=readonly(freqs.copy()),
        h11=readonly(H[0]),
        h12=readonly(H[1]),
        h21=readonly(H[2]),
        h22=readonly(H[3]),
        htot=readonly(htot),
        valid=readonly(valid),
        mode=readonly(mode.astype(np.uint8)),
    )


def averaged_spectra(avg: SpectralAverager, est: SpectralEstimator, scaling: Literal["density", "spectrum", "raw"]) -> dict[str, NDArray[np.complex128]]:
    """Averaged auto/cross spectra (P11 … P2y2, plus P21), scaled like scipy.signal.csd.

    ``'raw'`` returns the unscaled averaged ``conj(X)·Y`` (two-sided-style
    bins, no doubling). Averages are bias-corrected (divided by Σw).
    """
    mean = avg.mean()
    if scaling != "raw":
        mean = scale_spectra(mean, est.scale_factor(scaling), est.n)
    out = {name: mean[i].copy() for i, name in enumerate(SPECTRA_NAMES)}
    out["P21"] = np.conj(out["P12"])
    return out
