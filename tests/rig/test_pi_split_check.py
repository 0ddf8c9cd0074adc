"""The apex split check of ``pi-spectrogram`` (:mod:`workbench.experiments.lib.apex_split`: ``split_peaks``, ``split_agreement``) on synthetic two-mode
responses built with ``scipy.signal.freqs``: it passes when the estimate shows what the truth shows, and fails
when the estimate misses a second mode the truth has, or shows one the truth does not (the check can fail)."""

from __future__ import annotations

import numpy as np
import scipy.signal as ss

from workbench.experiments.lib.apex_split import split_agreement, split_codes, split_peaks

FREQS = np.arange(1025) * 200.0 / 2048


def _modes(*modes: tuple[float, float, float]) -> np.ndarray:
    """|Σ g ω² / (s² + 2ζω s + ω²)| over FREQS for modes (f Hz, ζ, gain)."""
    w = 2 * np.pi * FREQS
    h = np.zeros(FREQS.size, dtype=complex)
    for f, z, g in modes:
        wn = 2 * np.pi * f
        h += ss.freqs([g * wn * wn], [1.0, 2 * z * wn, wn * wn], worN=w)[1]
    return np.abs(h)


TWO = _modes((2.5, 0.09, 1.0), (5.0, 0.09, 0.6))
ONE = _modes((4.0, 0.09, 1.0))


def test_a_clean_two_mode_response_shows_both_and_a_one_mode_response_one() -> None:
    two = split_peaks(FREQS, TWO, 2.5, 5.0)
    assert two["near_f1"] and two["near_f2"] and two["both_modes"] and two["noise_db"] == 0.0
    one = split_peaks(FREQS, ONE, 4.0, 5.7)
    assert one["near_f1"] and not one["near_f2"]


def test_noise_peaks_do_not_count_as_modes() -> None:
    """A ripple of 3 dB peaks all over the band: a 3 dB bump at the second mode does not stand out from them."""
    ripple = 10 ** (1.5 * np.sin(2 * np.pi * FREQS / 0.9) / 20)
    noisy = split_peaks(FREQS, ONE * ripple, 4.0, 5.7)
    assert not noisy["near_f2"] and noisy["noise_db"] >= 2.0
    assert noisy["near_f1"]  # the mode itself (a ~20 dB peak) still stands out


def test_the_check_passes_when_the_estimate_agrees_with_the_truth() -> None:
    pairs = [(split_peaks(FREQS, TWO, 2.5, 5.0), split_peaks(FREQS, TWO * 1.3, 2.5, 5.0))] * 4
    pairs += [(split_peaks(FREQS, ONE, 4.0, 5.7), split_peaks(FREQS, ONE * 0.8, 4.0, 5.7))] * 4
    ag = split_agreement(pairs)
    assert ag == {"truth_two": 4, "shown_both": 4, "truth_one": 4, "invented": 0, "passed": True}


def test_the_check_fails_when_the_estimate_misses_the_split() -> None:
    """The truth has two modes; the estimate merged them into one peak between them."""
    merged = _modes((3.6, 0.3, 1.0))
    pairs = [(split_peaks(FREQS, TWO, 2.5, 5.0), split_peaks(FREQS, merged, 2.5, 5.0))] * 5
    ag = split_agreement(pairs)
    assert ag["truth_two"] == 5 and ag["shown_both"] == 0 and not ag["passed"]


def test_the_check_fails_when_the_estimate_invents_a_second_mode() -> None:
    """The truth has one mode; the estimate has a clear second peak at the second mode's frequency."""
    invented = _modes((4.0, 0.09, 1.0), (5.7, 0.05, 0.4))
    pairs = [(split_peaks(FREQS, ONE, 4.0, 5.7), split_peaks(FREQS, invented, 4.0, 5.7))] * 5
    ag = split_agreement(pairs)
    assert ag["truth_one"] == 5 and ag["invented"] == 5 and not ag["passed"]
    # 4 of 5 right is within the 80 % the check allows, 3 of 5 is not
    ok = (split_peaks(FREQS, ONE, 4.0, 5.7), split_peaks(FREQS, ONE, 4.0, 5.7))
    bad = pairs[0]
    assert split_agreement([ok] * 4 + [bad])["passed"]
    assert not split_agreement([ok] * 3 + [bad] * 2)["passed"]


def _result(theta: np.ndarray, t: np.ndarray) -> object:
    """A run's record with a given true configuration over time and white valve commands."""
    from workbench.hil import RunRecord

    rng = np.random.default_rng(1)
    columns = {"t_s": t, "u1_v": rng.normal(size=t.size), "u2_v": rng.normal(size=t.size)}
    truth = {"sim_time_s": t, "theta_rad": theta, "modal_frequencies_hz": np.ones((t.size, 2))}
    return RunRecord("cosim", None, t.size, float(t[-1]), {}, columns, [], [], [], {}, 0.0, truth_columns=truth)


def test_the_window_response_of_a_fixed_configuration_is_the_plant_s_own() -> None:
    """Averaging over a window where nothing moves gives back ``frequency_response`` at that configuration
    (weights sum to one); a moving configuration gives a different response."""
    from plant_emulator.model.modes import frequency_response
    from workbench.experiments.lib.windowed_plant_response import window_response

    t = np.arange(4000) * 0.005
    fixed = np.tile([1.2, 0.4], (t.size, 1))
    h, tk, w = window_response(_result(fixed, t), 19.0, FREQS, payload=True)  # type: ignore[arg-type]
    np.testing.assert_allclose(h, frequency_response(1.2, 0.4, FREQS, payload=True), rtol=1e-12, atol=1e-15)
    assert tk.min() >= 19.0 - 2048 / 200.0 and tk.max() <= 19.0 and np.all(w > 0)
    moving = np.column_stack([np.full(t.size, 1.2), np.linspace(0.2, 0.9, t.size)])
    h2, _, _ = window_response(_result(moving, t), 19.0, FREQS, payload=True)  # type: ignore[arg-type]
    assert np.max(np.abs(h2 - h)) > 0.1 * np.max(np.abs(h))


def test_split_codes_name_the_modes_each_response_shows_and_the_invented_ones() -> None:
    """One digit a transfer function (H_tot, H11, H12, H21, H22): 2 both modes, 1 the first only, 0 neither;
    a ``+`` per second mode the estimate shows where the truth shows none."""
    two, one, none = split_peaks(FREQS, TWO, 2.5, 5.0), split_peaks(FREQS, ONE, 4.0, 5.7), split_peaks(FREQS, np.zeros(FREQS.size), 4.0, 5.7)
    names = ("Htot", "H11", "H12", "H21", "H22")
    truth = dict(zip(names, (one, one, two, none, one)))
    estimate = dict(zip(names, (two, one, two, none, two)))
    assert split_codes(truth) == "11201"
    assert split_codes(estimate, truth) == "21202++"


def test_tf_magnitudes_take_h_tot_as_the_mean_of_the_four() -> None:
    from workbench.experiments.lib.windowed_plant_response import tf_magnitudes

    h = np.array([[[1.0, 2j], [-3.0, 4.0]], [[0.5, 0.5], [0.5, -1.5]]])
    mags = tf_magnitudes(h)
    np.testing.assert_allclose(mags["Htot"], [abs(1 + 2j - 3 + 4) / 4, 0.0])
    np.testing.assert_allclose(np.column_stack([mags[k] for k in ("H11", "H12", "H21", "H22")]), np.abs(h.reshape(2, 4)))
