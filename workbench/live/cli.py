"""``ralf-hil live [HOST:]PORT``: the live view of a rig whose services run on
their own (``ralf-plant`` etc., or ``docker compose``), as ``ralf-hil record``
taps them: zenoh and CAN settings from ``RALF_*`` and the options."""

from __future__ import annotations

import argparse
import json
import os
import signal
import threading
import time
from typing import Any

from rich.console import Console

console = Console(stderr=True)

ADDRESS_VARIABLE = "LIVE_ADDRESS"
"""Default of the address (docker-compose.yml's ``live`` service sets it); not a ``RALF_*`` setting."""


def cmd_live(args: argparse.Namespace) -> int:
    from protocol.errors import ConfigError
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import open_zenoh
    from workbench.live.params import ParamPanel
    from workbench.live.view import LiveView, LiveViewError, parse_address
    from workbench.recording.recorder import Recorder
    from workbench.recording.schemas import rig_topics
    from workbench.recording.tap import Tap, open_tap_bus

    address = args.address or os.environ.get(ADDRESS_VARIABLE) or "8765"
    overrides: dict[str, Any] = {"zenoh_listen": ""}
    if args.rig_id:
        overrides["rig_id"] = args.rig_id
    if args.connect:
        overrides["zenoh_connect"] = args.connect
    if args.can_port:
        overrides["can_port"] = args.can_port
    try:
        settings = load_settings(CommonSettings, overrides)
        host, port = parse_address(address)
        panel = ParamPanel(settings.rig_id) if args.params else None
        view = LiveView(host, port, rate_hz=args.rate, topics=rig_topics(settings.rig_id), params=panel)
    except (ConfigError, LiveViewError) as exc:
        console.print(f"[red]ralf-hil live: {' '.join(str(exc).split())}[/red]", highlight=False, soft_wrap=True)
        return 2
    recorder = Recorder(None, sample_rate_hz=settings.sample_rate_hz, node_id=settings.node_id, mirror=view)
    session = open_zenoh(settings)
    if view.params is not None:
        view.params.session = session
    bus = open_tap_bus(settings)
    tap = Tap(recorder, settings.rig_id, session=session, bus=bus)
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    print(f"live view of rig {settings.rig_id!r} on {view.url} ({args.rate:g} Hz per topic); Ctrl-C stops", flush=True)
    started = time.monotonic()
    try:
        while not stop.is_set() and (args.duration is None or time.monotonic() - started < args.duration):
            stop.wait(0.2)
    finally:
        tap.close()
        kernel_drops = int(getattr(bus, "kernel_drops", 0))
        bus.shutdown()
        recorded = recorder.close()  # its bounded queue's drops
        session.close()
        stats = view.close()
        stats.handoff_dropped, stats.can_socket_drops = recorded.dropped, kernel_drops
    print(json.dumps({"url": view.url, **stats.as_dict()}))
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "live",
        help="serve a rig whose services run on their own over the Foxglove WebSocket protocol",
        description="The live view (as `ralf-hil up --live`) of a rig started elsewhere: a tap on ralf/<rig>/** and the rig's CAN bus; "
        "zenoh and CAN settings from RALF_* and the options below.",
    )
    p.add_argument("address", nargs="?", default=None, metavar="[HOST:]PORT", help=f"where to serve (default: ${ADDRESS_VARIABLE}, else 8765 on 127.0.0.1)")
    p.add_argument("--rate", type=float, default=20.0, metavar="HZ", help="at most this many messages per second per topic (default: 20)")
    p.add_argument("--rig-id", default=None)
    p.add_argument("--connect", default=None, metavar="ENDPOINT[,ENDPOINT...]", help="zenoh endpoints of the services (default: RALF_ZENOH_CONNECT)")
    p.add_argument("--can-port", type=int, default=None, help="udp_multicast port (default: RALF_CAN_PORT)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many wall-clock seconds")
    p.add_argument(
        "--params",
        action="store_true",
        help="serve the controller's parameters in Foxglove's parameter panel (a rig with controller.param_commands=true; changes as the tool role)",
    )
    p.set_defaults(func=cmd_live)
