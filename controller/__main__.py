"""``ralf-controller`` / ``python -m controller``: the emulated MVME CPU.

Ctrl-C is answered from the first line of :func:`main`: the rig's modules
(numpy, numba, zenoh) are imported after it (:mod:`service_kit.interrupt`)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from typing import TYPE_CHECKING

from protocol.setting_hints import refuse_misspelt_settings
from service_kit.interrupt import end, end_at_once_on_ctrl_c

if TYPE_CHECKING:
    import zenoh

    from controller.service import ControllerService
    from protocol.settings import ControllerSettings
    from service_kit.waits import Awaited

EXIT_PLANT_FAULT = 3
EXIT_MONITOR_STOP = 4

log = logging.getLogger("controller")


def control(settings: ControllerSettings, session: zenoh.Session, stop: threading.Event) -> int:
    from controller.dsp_port import ZenohDspPort
    from controller.plant_link import PlantLink, link_can_filters
    from controller.service import ControllerService
    from service_kit.relink import Rebinds, relinking
    from service_kit.runtime import build_or_config_error
    from service_kit.transport import open_can_bus
    from service_kit.waits import log_waits

    bus = open_can_bus(settings, consumes=link_can_filters(settings.node_id))
    try:
        port = ZenohDspPort(session, settings.rig_id)
        service = build_or_config_error("controller configuration", lambda: ControllerService(settings, None, PlantLink(bus, settings.node_id), port=port))
        # a claimed zenoh id: the port moves to a new session; the loop and the CAN side go on (service_kit/relink.py)
        movable: list[Rebinds] = [port, *([service.param_commands] if service.param_commands is not None else [])]  # ralf-hil param's keys move too
        with relinking(settings, session, movable) as watch:
            try:
                log.info("controller up on rig %r: %s clock, %.0f Hz, OATF %s", settings.rig_id, settings.clock, settings.sample_rate_hz, settings.oatf_mode)
                started = threading.Event()
                log_waits(start_up_waits(service, settings), log, started)
                try:
                    result = service.run(stop)
                finally:
                    started.set()
                service.finish(result)
                log.info("run ended after %d ticks (%.2f s simulated): %s", result.ticks, result.sim_time_s, result.counters)
            finally:
                watch.halt()
                service.close()
    finally:
        bus.shutdown()
    if result.error:
        log.error("run ended with a fault: %s", result.error)
        return EXIT_MONITOR_STOP if result.error.startswith("stopped by monitor") else EXIT_PLANT_FAULT
    return 0


def start_up_waits(service: ControllerService, settings: ControllerSettings) -> list[Awaited]:
    """What the controller waits for before tick 0, in order, read from its state
    (:mod:`service_kit.waits`): the plant node's heartbeat, its start, the DSP."""
    from protocol.can_map import NmtState
    from service_kit.waits import Awaited

    plant, node = service.plant, f"plant node {settings.node_id}"
    return [
        Awaited(f"the {node} on CAN {settings.can_interface} (its boot-up or heartbeat)", lambda: plant.last_heartbeat is not None, f"{node} heard"),
        Awaited(
            f"the {node} to start (NMT reset, SDO configuration, OPERATIONAL)",
            lambda: plant.node_state == NmtState.OPERATIONAL or service.ready_at is not None,
            f"{node} operational",
        ),
        Awaited(
            "the DSP on zenoh (its answer to the run-start reset)",
            lambda: service.ready_at is not None,
            lambda: "DSP ready" if service.dsp.dsp_alive else "no DSP answered; controlling without identification",
        ),
    ]


def main(argv: Sequence[str] | None = None) -> int:
    end_at_once_on_ctrl_c("ralf-controller")  # before numpy, numba and zenoh load
    refuse_misspelt_settings("ralf-controller", "controller", argv)  # before them too: a misspelt name is refused at once
    from protocol.settings import ControllerSettings
    from service_kit.runtime import run_service

    return end(
        run_service(
            "ralf-controller", "The emulated MVME CPU: 200 Hz PI joint control, OATF input shaping, link to the DSP.", ControllerSettings, control, argv
        )
    )


if __name__ == "__main__":
    raise SystemExit(main())
