"""What a dither on the valve commands costs (thesis §4.2.1 metrics) and what the D/A actually sent.

The controller's opt-in dither (``controller/excitation.py``) is added to both
valve commands after the PI, before the D/A; the record keeps the PI's output
(``pi1_v``, ``pi2_v``) and the D/A's value (``u1_v``, ``u2_v``), so their
difference is the dither as sent (with the D/A's rounding). Its cost is the
RMS deflection velocity and acceleration over the whole run
(:func:`workbench.experiments.analysis.costs_over`) against an undithered run
of the same seed and trajectory.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from workbench.experiments.analysis import costs_over
from workbench.hil import RunRecord

__all__ = ["DA_LSB_V", "dither_cost", "expected_sent_rms_v", "sent_dither_rms_v", "whole_run_costs"]

DA_LSB_V = 20.0 / 4096
"""The valve D/A's step (V): 12 bits over ±10 V."""


def whole_run_costs(res: RunRecord) -> dict[str, list[float]]:
    """The §4.2.1 costs (RMS deflection velocity and acceleration per link) over the whole run."""
    return costs_over(res.deflections, np.ones(res.t_s.size, dtype=bool), res.sample_period_s)


def sent_dither_rms_v(res: RunRecord) -> list[float]:
    """Per valve, the RMS of what the D/A sent above the PI's output (``u − pi``): the dither as sent."""
    rec = res.controller_record()
    sent = np.vstack(
        [
            np.asarray(rec["u1_v"], dtype=float) - np.asarray(rec["pi1_v"], dtype=float),
            np.asarray(rec["u2_v"], dtype=float) - np.asarray(rec["pi2_v"], dtype=float),
        ]
    )
    return [float(x) for x in np.sqrt(np.mean(sent**2, axis=1))]


def expected_sent_rms_v(amplitude_v: float) -> float:
    """The RMS of a dither of RMS ``amplitude_v`` after the D/A's rounding: √(A² + LSB²/12)."""
    return math.hypot(amplitude_v, DA_LSB_V / math.sqrt(12.0))


def dither_cost(base: RunRecord, dithered: RunRecord, amplitude_v: float) -> dict[str, Any]:
    """One dithered run against the undithered ``base``: the dither as sent, the costs and their ratios per link."""
    base_cost = whole_run_costs(base)
    cost = whole_run_costs(dithered)
    return {
        "amplitude_v": amplitude_v,
        "sent_rms_v": sent_dither_rms_v(dithered),
        "velocity_rms": cost["velocity_rms"],
        "acceleration_rms": cost["acceleration_rms"],
        "velocity_ratio": [a / b for a, b in zip(cost["velocity_rms"], base_cost["velocity_rms"])],
        "acceleration_ratio": [a / b for a, b in zip(cost["acceleration_rms"], base_cost["acceleration_rms"])],
    }
