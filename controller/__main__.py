"""``ralf-controller`` / ``python -m controller``: the emulated MVME CPU.

Ctrl-C is answered from the first line of :func:`main`: the rig's modules
(numpy, numba, zenoh) are imported after it (:mod:`service_kit.interrupt`)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING

from service_kit.interrupt import end_at_once_on_ctrl_c

if TYPE_CHECKING:
    import zenoh

    from protocol.settings import ControllerSettings

EXIT_PLANT_FAULT = 3
EXIT_MONITOR_STOP = 4

log = logging.getLogger("controller")


def control(settings: ControllerSettings, session: zenoh.Session, stop: threading.Event) -> int:
    from controller.plant_link import PlantLink
    from controller.service import ControllerService
    from service_kit.runtime import build_or_config_error
    from service_kit.transport import open_can_bus

    bus = open_can_bus(settings)
    try:
        service = build_or_config_error("controller configuration", lambda: ControllerService(settings, session, PlantLink(bus, settings.node_id)))
        try:
            log.info("controller up on rig %r: %s clock, %.0f Hz, OATF %s", settings.rig_id, settings.clock, settings.sample_rate_hz, settings.oatf_mode)
            result = service.run(stop)
            if settings.run_record:
                service.save(settings.run_record, result)
            log.info("run ended after %d ticks (%.2f s simulated): %s", result.ticks, result.sim_time_s, result.counters)
        finally:
            service.close()
    finally:
        bus.shutdown()
    if result.error:
        log.error("run ended with a fault: %s", result.error)
        return EXIT_MONITOR_STOP if result.error.startswith("stopped by monitor") else EXIT_PLANT_FAULT
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    end_at_once_on_ctrl_c("ralf-controller")  # before numpy, numba and zenoh load
    from protocol.settings import ControllerSettings
    from service_kit.runtime import run_service

    return run_service(
        "ralf-controller", "The emulated MVME CPU: 200 Hz PI joint control, OATF input shaping, link to the DSP.", ControllerSettings, control, argv
    )


if __name__ == "__main__":
    raise SystemExit(main())
