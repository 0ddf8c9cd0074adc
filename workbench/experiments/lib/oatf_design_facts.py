"""What an OATF design is, in numbers: its delay and taps, and how well it cancels a given mode.

``|F|`` at the mode's pole ``z = e^(s Ts)`` (``s = -zeta wn + j wn sqrt(1 - zeta^2)``)
is 0 when the design cancels the mode exactly (§3.3: the OATF places its
zeros on the identified poles); ``|F(j 2 pi f)|`` is its steady-state gain
at the mode's frequency.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from controller.oatf import OatfFilter, transfer_function

__all__ = ["abs_at_pole", "design_facts"]


def abs_at_pole(stage: Any, frequency_hz: float, zeta: float) -> float:
    """``|F(z)|`` of one OATF stage at the pole ``z = e^(s Ts)`` of a mode (``frequency_hz``, ``zeta``): 0 when the stage cancels it."""
    wn = 2 * math.pi * frequency_hz
    pole = complex(-zeta * wn, wn * math.sqrt(1 - zeta * zeta))
    return float(abs(transfer_function([np.exp(pole * stage.sample_period_s)], [stage])[0]))


def design_facts(filt: OatfFilter, mode_hz: float, mode_zeta: float) -> dict[str, Any]:
    """The first stage of ``filt``: design damping, delay (samples, s), taps, ``Σ|a|``, ``|F|`` at the mode's frequency and at its pole."""
    st = filt.stages[0]
    return {
        "design_zeta": st.zeta,
        "delay_samples": st.delay_samples,
        "delay_s": st.delay_s,
        "coefficients": list(st.coefficients),
        "abs_coefficient_sum": st.abs_coefficient_sum,
        "abs_F_at_mode": float(abs(filt.frequency_response([mode_hz])[0])),
        "abs_F_at_mode_pole": abs_at_pole(st, mode_hz, mode_zeta),
    }
