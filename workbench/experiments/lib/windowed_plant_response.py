"""The plant's own transfer functions as an estimate from one window of a run sees them.

An identifier's estimate at time t averages the data of its window (the ETFE:
N samples under a Hann taper; a recursive model: an exponential memory), and
along a trajectory the configuration, hence the modes, moves within that
window. :func:`window_response` averages the plant's
``frequency_response`` (the assumed-modes model of thesis §2.2, [2-1], [2-2]) over the true
configurations of the window with the weight each instant has in the
estimate: the reference an on-line estimate is compared with.
"""

from __future__ import annotations

import numpy as np
import scipy.signal as ss

from workbench.experiments.analysis import moving_average
from workbench.experiments.lib.identifier_replay import record_inputs
from workbench.rig_record import RunRecord

__all__ = ["WINDOW_POINTS", "tf_magnitudes", "window_response"]

WINDOW_POINTS = 41
"""Configurations across a window at which the plant's own response is averaged (:func:`window_response`)."""


def window_response(
    res: RunRecord,
    t_end: float,
    freqs: np.ndarray,
    payload: bool,
    points: int = WINDOW_POINTS,
    memory_s: float | None = None,
    *,
    fft_width: int = 2048,
    fs_hz: float = 200.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The plant's own transfer functions as an estimate from the window ending at ``t_end`` sees them:
    ``frequency_response`` at ``points`` configurations across the window (``fft_width`` samples; the true θ),
    averaged (complex) with the weight each instant has in the ETFE's cross-spectra, the squared Hann window
    times the input's local power in 2–10 Hz (1-s running mean of the band-passed valve commands' squares).
    ``memory_s``: a recursive estimator's exponential memory instead (weights ``exp(−age/memory_s)`` over five
    memories, times the same local power). Returns ``(H (n_freqs, 2, 2), the instants, their weights)``."""
    from plant_emulator.model.modes import frequency_response

    t = res.t_s
    span = fft_width / fs_hz if memory_s is None else 5.0 * memory_s
    tk = np.linspace(t_end - span, t_end, points + 2)[1:-1]
    theta = res.true_theta(tk)
    u = record_inputs(res)
    sos = ss.butter(4, (2.0, 10.0), btype="bandpass", fs=fs_hz, output="sos")
    power = ss.sosfiltfilt(sos, u, axis=1) ** 2
    local = moving_average(power.sum(axis=0), int(fs_hz))
    shape = np.sin(np.pi * (tk - (t_end - span)) / span) ** 4 if memory_s is None else np.exp(-(t_end - tk) / memory_s)  # Hann², or the memory
    weights = shape * np.interp(tk, t, local)  # times the local input power
    h = np.zeros((freqs.size, 2, 2), dtype=complex)
    for k in range(points):
        h += weights[k] * frequency_response(float(theta[k, 0]), float(theta[k, 1]), freqs, payload=payload)
    return h / max(float(weights.sum()), 1e-300), tk, weights


def tf_magnitudes(h: np.ndarray) -> dict[str, np.ndarray]:
    """|H_tot| (the mean of the four, as the DSP forms it) and |H_ij| of a ``(n, 2, 2)`` response."""
    return {
        "Htot": np.abs(h.reshape(h.shape[0], 4).mean(axis=1)),
        "H11": np.abs(h[:, 0, 0]),
        "H12": np.abs(h[:, 0, 1]),
        "H21": np.abs(h[:, 1, 0]),
        "H22": np.abs(h[:, 1, 1]),
    }
