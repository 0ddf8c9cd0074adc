"""``ralf-dsp`` / ``python -m dsp_service``: the emulated C40 DSP board."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from dsp_service.service import DspService
from protocol.settings import DspSettings
from protocol.transport import open_zenoh
from rig.runtime import configure_logging, install_stop_handlers, parse_service_args


def main(argv: Sequence[str] | None = None) -> int:
    settings = parse_service_args(
        "ralf-dsp", "The emulated TI C40 DSP board: on-line FFT identification of RALF's transfer functions.", DspSettings, argv
    )
    configure_logging(settings.log_level, "dsp")
    stop = install_stop_handlers()
    log = logging.getLogger("dsp")
    session = open_zenoh(settings)
    try:
        service = DspService(settings, session)
        log.info("DSP board up on rig %r: N=%d, alpha=%.3g, emulated latency %.0f ms", settings.rig_id, settings.fft_width, settings.alpha, settings.emulated_latency_s * 1e3)
        try:
            service.run(stop)
        finally:
            service.close()
            log.info("DSP board stopped: %s", service.block.counters.as_dict())
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
