"""``ralf-dsp`` / ``python -m dsp_service``: the emulated C40 DSP board."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence

import zenoh

from dsp_service.service import DspService
from protocol.settings import DspSettings
from service_kit.runtime import build_or_config_error, run_service

log = logging.getLogger("dsp")


def serve(settings: DspSettings, session: zenoh.Session, stop: threading.Event) -> int:
    service = build_or_config_error("DSP configuration", lambda: DspService(settings, session))
    log.info("DSP board up on rig %r: N=%d, alpha=%.3g, emulated latency %.0f ms", settings.rig_id, settings.fft_width, settings.alpha, settings.emulated_latency_s * 1e3)
    try:
        service.run(stop)
    finally:
        service.close()
        log.info("DSP board stopped: %s", service.block.counters.as_dict())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    return run_service("ralf-dsp", "The emulated TI C40 DSP board: on-line FFT identification of RALF's transfer functions.", DspSettings, serve, argv)


if __name__ == "__main__":
    raise SystemExit(main())
