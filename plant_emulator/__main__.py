"""``ralf-plant`` / ``python -m plant_emulator``: RALF behind a CANopen analog I/O node."""

from __future__ import annotations

import logging
from collections.abc import Sequence

from plant_emulator.service import serve
from protocol.settings import PlantSettings
from protocol.transport import open_can_bus, open_zenoh
from rig.runtime import configure_logging, install_stop_handlers, parse_service_args


def main(argv: Sequence[str] | None = None) -> int:
    settings = parse_service_args(
        "ralf-plant", "RALF, the flexible two-link hydraulic arm, with its sensors and 12-bit A/D and D/A on a CANopen node.", PlantSettings, argv
    )
    configure_logging(settings.log_level, "plant")
    stop = install_stop_handlers()
    log = logging.getLogger("plant")
    session = open_zenoh(settings)
    try:
        bus = open_can_bus(settings)
        try:
            log.info("plant up on rig %r: node %d on %s:%s, %s clock", settings.rig_id, settings.node_id, settings.can_interface, settings.can_channel, settings.clock)
            serve(settings, session, bus, stop)
        finally:
            bus.shutdown()
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
