"""Spectrum features on spectra whose answers are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from workbench.experiments.lib.spectrum_features import band_below, dominant_peak_hz, magnitude_agreement, roughness_db

F = np.linspace(0.0, 20.0, 201)


def test_dominant_peak_skips_invalid_bins_and_the_band_edges() -> None:
    mag = 1.0 / (1 + (F - 5.0) ** 2) + 2.0 * (F > 15)
    valid = np.ones_like(F, dtype=bool)
    assert dominant_peak_hz(F, mag, valid, (1.0, 12.0)) == pytest.approx(5.0)
    valid[(F > 4.5) & (F < 5.5)] = False
    assert dominant_peak_hz(F, mag, valid, (1.0, 12.0)) in (pytest.approx(4.5), pytest.approx(5.5))
    assert math.isnan(dominant_peak_hz(F, mag, np.zeros_like(valid), (1.0, 12.0)))


def test_roughness_is_the_rms_second_difference_in_db() -> None:
    valid = np.ones_like(F, dtype=bool)
    assert roughness_db(F, 10 ** (0.05 * F), valid, (1.0, 20.0)) == pytest.approx(0.0, abs=1e-9)  # linear in dB
    db = np.where(np.arange(F.size) % 2 == 0, 1.0, -1.0)  # alternating ±1 dB: second difference ±4 dB
    assert roughness_db(F, 10 ** (db / 20), valid, (1.0, 20.0)) == pytest.approx(4.0)
    valid[::2] = False  # no run of 3 valid bins left
    assert math.isnan(roughness_db(F, 10 ** (db / 20), valid, (1.0, 20.0)))


def test_band_below() -> None:
    mag = np.abs(F - 10.0)
    assert band_below(F, mag, 10.0, 1.0) == (pytest.approx(9.0), pytest.approx(11.0))
    assert band_below(F, mag, 3.0, 1.0) is None


def test_magnitude_agreement() -> None:
    ref = np.where(F > 1.0, 1.0, 0.0)
    other = ref * (1 + 1e-3 * (F > 30)) + 0j
    other[F > 15] *= 1.01
    got = magnitude_agreement(F, ref, other, (0.5, 10.0))
    assert got["valid_bins"] == int(np.sum(F > 1.0))
    assert got["max_rel_diff"] == pytest.approx(0.01)
    assert got["max_rel_diff_0.5_10Hz"] == pytest.approx(0.0)
    assert math.isnan(magnitude_agreement(F, ref, other, (0.0, 0.5))["max_rel_diff_0_0.5Hz"])
