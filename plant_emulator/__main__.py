"""``ralf-plant`` / ``python -m plant_emulator``: RALF behind a CANopen analog I/O node.

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

    from protocol.settings import PlantSettings

log = logging.getLogger("plant")


def serve_on_bus(settings: PlantSettings, session: zenoh.Session, stop: threading.Event) -> int:
    from plant_emulator.canopen_node import node_can_filters
    from plant_emulator.plant_factory import build_plant_model
    from plant_emulator.service import serve
    from service_kit.transport import open_can_bus

    model = build_plant_model(settings)  # a bad FMU is refused (one line, exit 2) before the bus opens
    try:
        bus = open_can_bus(settings, consumes=node_can_filters(settings.node_id))
    except BaseException:
        model.close()
        raise
    try:
        log.info(
            "plant up on rig %r: node %d on %s:%s, %s clock, model %s",
            settings.rig_id,
            settings.node_id,
            settings.can_interface,
            settings.can_channel,
            settings.clock,
            settings.model,
        )
        serve(settings, session, bus, stop, model=model, relink=True)  # a claimed zenoh id: the test port moves to a new session
    finally:
        bus.shutdown()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    end_at_once_on_ctrl_c("ralf-plant")  # before numpy, numba and zenoh load
    refuse_misspelt_settings("ralf-plant", "plant", argv)  # before them too: a misspelt name is refused at once
    from protocol.settings import PlantSettings
    from service_kit.runtime import run_service

    return end(
        run_service(
            "ralf-plant",
            "RALF, the flexible two-link hydraulic arm, with its sensors and 12-bit A/D and D/A on a CANopen node.",
            PlantSettings,
            serve_on_bus,
            argv,
        )
    )


if __name__ == "__main__":
    raise SystemExit(main())
