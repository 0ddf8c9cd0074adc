"""The recursive ARX model's change detector (``change_detection``): Page's CUSUM test on the level
of the model's a-priori equation errors; at an alarm the model discounts its old data
(:meth:`.arx.RecursiveArx.discount`)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from dsp_service.arx_config import ArxConfig


class ChangeDetector:
    """CUSUM of the log error ratio on each batch's a-priori errors (one :meth:`update` per batch)."""

    def __init__(self, cfg: ArxConfig) -> None:
        self.cfg = cfg
        self.statistic = 0.0  #: the CUSUM S
        self.detected = 0  #: alarms since the reset
        self._ref_log = 0.0
        self._ref_count = 0
        self._since_alarm = 1 << 60

    def update(self, e: NDArray[np.float64], n: int, residual_power: float) -> bool:
        """True at an alarm on the batch's a-priori errors ``e`` (``n`` model samples).

        ``z`` = the batch's mean of ``min(e²/σ², 50)`` (σ² the residual power),
        ``g = ln z − r`` with ``r`` the running mean of ``ln z`` over
        ``change_reference_s`` (the steady level: the a-priori errors of a model
        that fits stay near it whatever their distribution),
        ``S ← max(0, S + g − ν)``; ``S > h`` is a change (Page's test on a
        shift of the log error level). After an alarm the test rests for
        ``change_refractory_s`` (the new model converging raises the errors
        too). Detection starts once the reference has run for its own span."""
        c = self.cfg
        z = float(np.mean(np.minimum(e * e / residual_power, 50.0)))
        if not z > 0:
            return False
        lz = math.log(z)
        ref_samples = c.change_reference_s * c.model_rate_hz
        if self._ref_count == 0:
            self._ref_log = lz
        g = lz - self._ref_log
        self._ref_log += (lz - self._ref_log) * min(1.0, n / ref_samples)
        self._ref_count += n
        self._since_alarm += n
        if self._ref_count < ref_samples or self._since_alarm < c.change_refractory_s * c.model_rate_hz:
            return False
        self.statistic = max(0.0, self.statistic + g - c.change_drift)
        if self.statistic > c.change_threshold:
            self.statistic = 0.0
            self._since_alarm = 0
            self.detected += 1
            return True
        return False
