"""Where spectrogram columns peak (:mod:`workbench.experiments.lib.tf_spectrogram`): downloads whose |H| peaks at the
true mode against a plain spectrogram of an output dominated by slow motion (scipy's ``ShortTimeFFT`` columns)."""

from __future__ import annotations

import numpy as np
import scipy.signal as ss

from workbench.experiments.analysis import plain_spectrogram
from workbench.experiments.lib.tf_spectrogram import clutter, downloads_with_estimate, spectrogram_figure

FS = 200.0
WIDTH = 2048
FREQS = np.arange(WIDTH // 2 + 1) * FS / WIDTH
MODE_HZ = 4.0


def _downloads() -> dict[str, np.ndarray]:
    """Six downloads every 5 s: none in the first (no estimate yet), then one resonance at MODE_HZ, bins below 1 Hz invalid (0)."""
    h = np.abs(ss.freqs([1.0], [1.0, 2 * 0.09 * 2 * np.pi * MODE_HZ, (2 * np.pi * MODE_HZ) ** 2], worN=2 * np.pi * FREQS)[1])
    h[FREQS < 1.0] = 0.0
    mags = np.tile(h, (6, 1))
    mags[0] = 0.0
    tf = {"freqs_hz": FREQS, "sim_time_s": 5.0 * np.arange(1, 7)}
    tf.update({f"{k}_mag": mags for k in ("H11", "H12", "H21", "H22", "Htot")})
    return tf


def test_the_downloads_peak_at_the_mode_and_the_plain_spectrogram_at_the_motion() -> None:
    t = np.arange(int(32 * FS)) / FS
    y = 1.0 * np.sin(2 * np.pi * 1.0 * t) + 0.05 * np.sin(2 * np.pi * MODE_HZ * t)  # slow motion dominates the output
    truth_t = np.arange(0.0, 32.0, 0.05)
    truth_f = np.column_stack([np.full(truth_t.size, MODE_HZ), np.full(truth_t.size, 6.0)])
    tf = _downloads()
    assert downloads_with_estimate(tf).tolist() == [False, True, True, True, True, True]
    plain = plain_spectrogram(y, WIDTH, FS)
    c = clutter(tf, plain, truth_t, truth_f, WIDTH / FS, (0.5, 12.0), 2.0)
    assert len(c.tf_cols) == 5 and c.tf_near == 1.0
    assert all(abs(col[1] - MODE_HZ) <= FS / WIDTH for col in c.tf_cols)
    assert c.st_cols and c.st_near == 0.0  # the plain columns peak at the 1 Hz motion, off both modes
    assert c.st_low > 0.9 > c.tf_low  # nearly all the output's power is slow; |H|² is not
    assert 0.0 < c.tf_low_valid < 1.0  # the bins below 1 Hz are invalid
    assert len(spectrogram_figure(tf, 5.0, plain, truth_t, truth_f, 12.0).axes) >= 6
