"""The poles of ``method='arx'``: the identifier's recursive ARX model (:mod:`.arx`), fed the same
batches as the ETFE's history, and its poles reported in the identifier's result types."""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import NDArray

from .arx import RecursiveArx
from .arx_regime_bank import RegimeBankState
from .identifier_config import IdentificationResult, IdentifierConfig, PoleEstimate, arx_config

log = logging.getLogger(__name__)


class ArxPoles:
    """The ARX model of one identifier configuration and the batches it has not regressed yet.

    ``carried``: the regime bank the previous model of the same identifier had learned (the plant's
    regimes, not the history's: a rebuilt model starts from them), else ``seed`` (a bank carried in
    from another run)."""

    def __init__(self, cfg: IdentifierConfig, carried: RegimeBankState | None, seed: RegimeBankState | None) -> None:
        self.cfg = cfg
        self.model = RecursiveArx(arx_config(cfg))
        self._batches: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []
        start = carried if carried is not None and carried.regimes else seed
        if start is not None:
            try:
                self.model.load_bank(start)
            except ValueError as exc:  # not expected (the same model fields); never let a rebuild fail half-way
                log.warning("the rebuilt ARX model starts without its regime bank: %s", exc)

    def push(self, inputs: NDArray[np.float64], outputs: NDArray[np.float64]) -> None:
        """Keep a batch for the next :meth:`result`."""
        self._batches.append((np.asarray(inputs, dtype=np.float64), np.asarray(outputs, dtype=np.float64)))

    def restart(self) -> None:
        """A gap: the kept batches dropped, the model's filters restarted (:meth:`.arx.RecursiveArx.restart`)."""
        self._batches.clear()
        self.model.restart()

    def result(self, etfe: IdentificationResult) -> IdentificationResult:
        """The kept batches regressed, then the model's poles in place of ``etfe``'s (whose valid fraction,
        history fill and averages are kept): confidence = the model's fill times
        ``min(1, relative strength / arx_confident_strength)``."""
        arx = self.model
        for u, y in self._batches:
            arx.update(u, y)
        self._batches.clear()
        fill = arx.fill
        poles = tuple(
            PoleEstimate(
                frequency_hz=p.frequency_hz,
                damping_ratio=p.damping_ratio,
                damping_fwhm=None,
                damping_vrm=None,
                natural_frequency_vrm_hz=None,
                magnitude=p.strength,
                prominence_db=20.0 * math.log10(max(p.relative_strength, 1e-12)),
                source="arx",
                confidence=fill * min(1.0, p.relative_strength / self.cfg.arx_confident_strength),
            )
            for p in arx.poles()
        )
        return IdentificationResult(
            poles=poles,
            confidence=fill if poles else 0.0,
            valid_fraction=etfe.valid_fraction,
            samples_in_history=etfe.samples_in_history,
            effective_averages=etfe.effective_averages,
        )

    def bank_state(self) -> RegimeBankState | None:
        """The model's regime bank as it stands, None without a bank or before its first batch with signal."""
        if not self.model.cfg.regime_bank:
            return None
        try:
            return self.model.bank_state()
        except ValueError:
            return None
