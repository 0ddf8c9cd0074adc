"""``ralf-controller`` / ``python -m controller``: the emulated MVME CPU."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from controller.plant_link import PlantLink
from controller.service import ControllerService
from protocol.settings import ControllerSettings
from protocol.transport import open_can_bus, open_zenoh
from rig.runtime import configure_logging, install_stop_handlers, parse_service_args

EXIT_PLANT_FAULT = 3
EXIT_MONITOR_STOP = 4


def main(argv: Sequence[str] | None = None) -> int:
    settings = parse_service_args(
        "ralf-controller", "The emulated MVME CPU: 200 Hz PI joint control, OATF input shaping, link to the DSP.", ControllerSettings, argv
    )
    configure_logging(settings.log_level, "controller")
    stop = install_stop_handlers()
    log = logging.getLogger("controller")
    session = open_zenoh(settings)
    try:
        bus = open_can_bus(settings)
        try:
            service = ControllerService(settings, session, PlantLink(bus, settings.node_id))
            try:
                log.info("controller up on rig %r: %s clock, %.0f Hz, OATF %s", settings.rig_id, settings.clock, settings.sample_rate_hz, settings.oatf_mode)
                result = service.run(stop)
                if settings.record:
                    service.save(settings.record, result)
                log.info("run ended after %d ticks (%.2f s simulated): %s", result.ticks, result.sim_time_s, result.counters)
            finally:
                service.close()
        finally:
            bus.shutdown()
    finally:
        session.close()
    if result.error:
        log.error("run ended with a fault: %s", result.error)
        return EXIT_MONITOR_STOP if result.error.startswith("stopped by monitor") else EXIT_PLANT_FAULT
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
