"""Opening the two transports from settings: a zenoh session and a python-can
bus. The interface is a setting, never a code change (design.md)."""

from __future__ import annotations

import json
import logging
import time
from typing import Any

import can
import zenoh

from protocol.settings import CommonSettings

log = logging.getLogger(__name__)

_zenoh_log_initialised = False


def zenoh_config(settings: CommonSettings) -> zenoh.Config:
    """A zenoh configuration from settings (mode, endpoints, scouting)."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.zenoh_mode))
    config.insert_json5("scouting/multicast/enabled", json.dumps(settings.zenoh_multicast_scouting))
    config.insert_json5("transport/link/tx/lease", json.dumps(settings.zenoh_lease_ms))
    connect = settings.endpoints("connect")
    listen = settings.endpoints("listen")
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    return config


def open_zenoh(settings: CommonSettings, retry_for_s: float = 30.0) -> zenoh.Session:
    """Open a zenoh session; a client retries while its router starts."""
    global _zenoh_log_initialised
    if not _zenoh_log_initialised:
        zenoh.init_log_from_env_or("error")
        _zenoh_log_initialised = True
    deadline = time.monotonic() + retry_for_s
    while True:
        try:
            return zenoh.open(zenoh_config(settings))
        except zenoh.ZError as exc:
            if time.monotonic() >= deadline:
                raise ConnectionError(f"cannot open zenoh session ({settings.zenoh_mode}, connect={settings.zenoh_connect!r}): {exc}") from exc
            log.warning("zenoh not reachable yet (%s); retrying", exc)
            time.sleep(0.5)


def open_can_bus(settings: CommonSettings, **kwargs: Any) -> can.BusABC:
    """Open the CAN bus named by the settings (udp_multicast, virtual, socketcan...)."""
    options: dict[str, Any] = {"interface": settings.can_interface, "channel": settings.can_channel}
    if settings.can_interface == "udp_multicast":
        options["port"] = settings.can_port
    options.update(kwargs)
    try:
        return can.Bus(**options)
    except Exception as exc:  # python-can raises several types by interface
        raise ConnectionError(f"cannot open CAN bus {settings.can_interface}:{settings.can_channel}: {exc}") from exc
