"""The ARX regime bank on disk (``RALF_ARX_REGIME_BANK_FILE``): loaded when a board
starts, written when it stops, at the edges of the board (the DSP service and the
co-simulation), never inside the identifier (docs/identification.md §5d)."""

from __future__ import annotations

import logging
from pathlib import Path

from dsp_service.arx_regime_bank import load_regime_bank, save_regime_bank
from dsp_service.identifier import Identifier
from protocol.errors import ConfigError
from protocol.settings import DspSettings

log = logging.getLogger(__name__)


def load_bank(identifier: Identifier, settings: DspSettings) -> bool:
    """Seed ``identifier``'s ARX bank from the settings' file if it exists (True); a missing file is a first
    run (False: the bank is learned on line and written at the stop). A file that is not a bank, or a bank of
    another model structure, is a :class:`ConfigError` naming the file: the board does not start with a bank
    it cannot use."""
    path = settings.regime_bank_path()
    if not path or not Path(path).exists():
        if path:
            log.info("regime bank %s not there yet: learned on line, written at the stop", path)
        return False
    try:
        state = load_regime_bank(path)
        identifier.seed_arx_bank(state)
    except ValueError as exc:
        raise ConfigError(f"arx_regime_bank_file: {exc}") from None  # the message names the file
    log.info("regime bank %s loaded: %d regime(s), signatures %s Hz", path, state.regimes, state.signature.round(3).tolist())
    return True


def save_bank(identifier: Identifier, settings: DspSettings) -> bool:
    """Write ``identifier``'s ARX bank to the settings' file (True); nothing when no file is set or the model
    has learned nothing yet (no batch with signal: an earlier file is kept). A full disk or a gone directory
    is logged (False): the board still stops, and its run's results stand; only the next run's bank is lost."""
    path = settings.regime_bank_path()
    state = identifier.arx_bank_state() if path else None
    if state is None:
        return False
    try:
        save_regime_bank(path, state)
    except OSError as exc:
        log.error("could not write the regime bank %s: %s", path, exc)
        return False
    log.info("regime bank %s written: %d regime(s)", path, state.regimes)
    return True
