"""``ralf-dsp`` / ``python -m dsp_service``: the emulated C40 DSP board.

Ctrl-C is answered from the first line of :func:`main`: the rig's modules
(numpy, numba, zenoh) are imported after it (:mod:`service_kit.interrupt`)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from functools import partial
from typing import TYPE_CHECKING

from protocol.setting_hints import refuse_misspelt_settings
from service_kit.interrupt import end, end_at_once_on_ctrl_c

if TYPE_CHECKING:
    import zenoh

    from dsp_service.service import DspService
    from protocol.settings import DspSettings
    from service_kit.waits import Awaited

log = logging.getLogger("dsp")


def serve(settings: DspSettings, session: zenoh.Session, stop: threading.Event) -> int:
    """One board per rig served (``rig_id``, then ``serve_rigs``), all on this session: each has
    its own identifier, inbox and thread, so one rig's batch never waits in another's queue,
    and their compiled steps (which release the GIL) run on as many cores as there are. A board
    serving one rig identifies in zenoh's batch callback (``inline``): no thread hand-off on the
    batch -> interrupt path (docs/dsp-performance.md)."""
    from dsp_service.service import DspService
    from service_kit import readiness
    from service_kit.relink import relinking
    from service_kit.runtime import build_or_config_error
    from service_kit.waits import log_waits

    rigs = settings.rig_ids

    inline = len(rigs) == 1

    def board(rig: str) -> DspService:
        return DspService(settings.model_copy(update={"rig_id": rig}), session, inline=inline)

    services = [build_or_config_error("DSP configuration", partial(board, rig)) for rig in rigs]
    log.info(
        "DSP board up on rig(s) %s: N=%d, alpha=%.3g, emulated latency %.0f ms",
        ", ".join(map(repr, rigs)),
        settings.fft_width,
        settings.alpha,
        settings.emulated_latency_s * 1e3,
    )
    readiness.mark_ready(settings.ready_file, log)  # boards built (kernels warm), subscribed
    for service in services:  # each board waits for its own rig's controller
        log_waits([controller_heard(service)], log, stop)
    threads = [threading.Thread(target=service.run, args=(stop,), name=f"dsp-{service.settings.rig_id}", daemon=True) for service in services[1:]]
    with relinking(settings, session, services) as watch:  # a claimed zenoh id: the boards move to a new session
        try:
            for thread in threads:
                thread.start()
            services[0].run(stop)
        finally:
            stop.set()
            for thread in threads:
                thread.join()
            watch.halt()
            for service in services:
                service.close()
                log.info("DSP board of rig %r stopped: %s", service.settings.rig_id, service.block.counters.as_dict())
    return 0


def controller_heard(service: DspService) -> Awaited:
    """What a board waits for once it is up (:mod:`service_kit.waits`): its rig's
    controller, heard when its run-start reset or a batch arrives."""
    from service_kit.waits import Awaited

    counters = service.block.counters
    rig = service.settings.rig_id
    return Awaited(
        f"the controller of rig {rig!r} on zenoh (its run-start reset or a batch)",
        lambda: counters.config_changes > 0 or counters.batches_accepted > 0,
        f"controller of rig {rig!r} heard",
    )


def main(argv: Sequence[str] | None = None) -> int:
    end_at_once_on_ctrl_c("ralf-dsp")  # before numpy, numba and zenoh load
    refuse_misspelt_settings("ralf-dsp", "dsp", argv)  # before them too: a misspelt name is refused at once
    from protocol.settings import DspSettings
    from service_kit.runtime import run_service

    return end(run_service("ralf-dsp", "The emulated TI C40 DSP board: on-line FFT identification of RALF's transfer functions.", DspSettings, serve, argv))


if __name__ == "__main__":
    raise SystemExit(main())
