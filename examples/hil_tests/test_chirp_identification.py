"""Chirps on both valves let the identifier find the arm's first mode.

The arm holds still (``tip_speed_in_s=0.01``: the trajectory crawls), so the
PI's valve commands carry almost nothing for the DSP's ETFE to identify.
Stimulus profiles replace both valve commands with chirps (docs/stimulus.md:
while one is active it replaces the PI's command before the D/A, and the
batches to the DSP carry the D/A's value, the chirp): valve 2 sweeps 2 to
8 Hz over 6 s while valve 1 sweeps 8 to 2 Hz, twice. The sweeps cross the
first mode (4.52 Hz) and stay below the second (8.68 Hz); the opposite
directions keep the two inputs apart, so the ETFE's 2x2 solve [2-21 .. 2-24]
has both columns; two sweeps keep its history (N 1024: 5.12 s) full of
excitation to the run's end. The checks: the identified first mode
(``f_id_hz``) follows the plant's true one once the history is full, and the
link deflections stay inside the sensors' ranges (±0.575 and ±0.555 in), on
which the identification depends.

Why this chirp. A 1 V chirp on valve 2 alone, 1 to 8 Hz over 6 s,
identifies 8.3-9.5 Hz, and up to 18 Hz with another start and smoothing,
for a true 4.52 Hz. Two causes, both in the data, not in the stimulus path
(the batches carry the applied chirp volts, sample for sample):

* the valves are velocity sources, so a chirp's low frequencies swing the
  links hard: at 1 V link 2's deflection passes its sensor's range, the A/D
  clips at ±0.555 in (about 650 of 2400 samples; the plant's EMCY
  INPUT_SATURATED) and the output is no longer a linear response of the
  command. At 0.1 V it stays inside (0.43 in); on valve 1, 0.05 V alone
  already clips link 1's sensor (±0.575 in), hence 0.03 V there;
* valve 2 alone rings mostly the second mode in link 2 (the offline H1 of
  ``u2_v`` to ``defl2_in`` peaks at 8.6 Hz), and the ETFE reports the
  strongest (low-weighted) peak of ``H_tot``: without clipping, valve 2 alone at 0.1 V
  still gives 4.1-5.1 Hz with stretches of 6.2-8.8 Hz. With both valves
  driven the first mode leads throughout.

Measured on the co-simulated rig (14 s, seed 0): the identifier reports from
5.35 s on, once its history is full; its first readings, up to 6 s, wander
(2.8-9.1 Hz), then it holds 4.66-4.82 Hz, a worst error of 6.5 % (the same,
6.5 %, with the plant's seed 1 and with chirps starting at their peak,
``phase_deg=0``); the largest deflections are 0.445 in (link 1) and
0.431 in (link 2). Tighter limits fail each check: a 5 % tolerance
(``within 6.545 % ... against a tolerance of 5 %``), ±70 % of the ranges
(``-0.4447 in at 5.06 s``, ``0.4306 in at 12.97 s``).
"""

from __future__ import annotations

import pytest

from workbench.checks import check, mode_frequency_within, signal, stays_within

VALVE2_V = 0.1
"""The chirp's amplitude on valve 2 (V; the D/A's value while it is active)."""
VALVE1_V = 0.03
"""The chirp's amplitude on valve 1 (V; 0.05 V alone clips link 1's deflection sensor)."""
SWEEP_S = 6.0
"""One sweep's length (s): valve 2 sweeps 2 to 8 Hz, valve 1 8 to 2 Hz, linear, each starting from 0 V."""
SWEEPS_AT_S = (1.0, 7.0)
"""When each pair of sweeps starts (simulated s)."""
IDENTIFIED_FROM_S = 6.0
"""The identifier reports from 5.35 s (its 1024-sample history full); its first readings wander up to 6 s."""
MODE_TOLERANCE = 0.10
"""Identified first mode within this fraction of the true one (measured worst: 6.5 %; the second mode is 92 % above)."""
LINK1_RANGE_IN = 0.575
LINK2_RANGE_IN = 0.555
"""The deflection sensors' ends of range (in): beyond them the A/D clips."""


@pytest.mark.rig_settings(
    controller={"tip_speed_in_s": 0.01, "tf_download_samples": 0},
    dsp={"fft_width": 1024, "alpha": 0.05, "smoothing": "window=9"},
)
def test_valve_chirps_identify_the_first_mode(rig):
    for at_s in SWEEPS_AT_S:
        rig.stimulus.chirp("valve.u2", VALVE2_V, 2.0, 8.0, SWEEP_S, phase_deg=-90.0, at_s=at_s)
        rig.stimulus.chirp("valve.u1", VALVE1_V, 8.0, 2.0, SWEEP_S, phase_deg=-90.0, at_s=at_s)
    record = rig.run(duration_s=14.0)
    assert record.error is None

    check(
        mode_frequency_within(signal(record, "f_id_hz"), signal(record, "truth.modal_frequencies_hz[0]"), rel_tol=MODE_TOLERANCE, from_s=IDENTIFIED_FROM_S),
        stays_within(signal(record, "defl1_in"), -0.95 * LINK1_RANGE_IN, 0.95 * LINK1_RANGE_IN),
        stays_within(signal(record, "defl2_in"), -0.95 * LINK2_RANGE_IN, 0.95 * LINK2_RANGE_IN),
    )
