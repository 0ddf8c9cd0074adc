"""A zenoh router in Python, opened from a zenohd configuration file.

``python -m service_kit.router /etc/ralf/zenoh-router.json5`` opens a zenoh
session in router mode from the file ``ralf-hil credentials`` writes (listen
endpoint, authentication of every client, the rig's access rules) and
routes until SIGTERM or SIGINT. It stands in for ``zenohd`` where the
``eclipse/zenoh`` image cannot be pulled (docker-compose.python-router.yml);
it routes and enforces the same configuration, but serves no plugin (REST,
storages: those are zenohd's), so ``curl :8000`` has no answer from it.

Bad input gets one line and exit 2: a missing or unreadable file, a file
that is not a zenoh configuration, a configuration that is not a router's,
an endpoint that cannot be listened on. With ``--ready-file`` it writes the
file a healthcheck reads (:mod:`service_kit.readiness`) once it listens.
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
from collections.abc import Sequence
from pathlib import Path

import zenoh

from service_kit import readiness
from service_kit.runtime import install_stop_handlers
from service_kit.transport import zenoh_error_text
from service_kit.zenoh_log import init_zenoh_log

log = logging.getLogger("router")


def load_router_config(path: Path) -> zenoh.Config:
    """The configuration in ``path``; :class:`ValueError` (one line) if it is not a router's."""
    if not path.is_file():
        raise ValueError(f"{path}: no such file (generate it with: ralf-hil credentials --out secrets)")
    try:
        config = zenoh.Config.from_file(str(path))
    except zenoh.ZError as exc:
        raise ValueError(f"{path}: not a zenoh configuration: {zenoh_error_text(exc)}") from None
    mode = json.loads(config.get_json("mode"))
    if mode != "router":
        raise ValueError(f"{path}: mode is {mode!r}, not 'router'")
    return config


def serve(config: zenoh.Config, stop: threading.Event, ready_file: str = "") -> None:
    """Route until ``stop``."""
    session = zenoh.open(config)
    try:
        log.info("zenoh router %s listening on %s", session.info.zid(), ", ".join(json.loads(config.get_json("listen/endpoints"))))
        readiness.mark_ready(ready_file, log)
        stop.wait()
    finally:
        readiness.clear(ready_file)
        session.close()
        log.info("zenoh router stopped")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m service_kit.router", description="A zenoh router opened from a zenohd configuration file (no plugins).")
    parser.add_argument("config", help="zenoh configuration (JSON5), e.g. the zenoh-router.json5 that `ralf-hil credentials` writes")
    parser.add_argument("--ready-file", default="", help="write this file once listening, remove it at exit (python -m service_kit.readiness FILE)")
    parser.add_argument("--log-level", default="INFO", choices=("DEBUG", "INFO", "WARNING", "ERROR"))
    args = parser.parse_args(argv)
    logging.basicConfig(level=getattr(logging, args.log_level), format="%(asctime)s router %(levelname)s %(name)s: %(message)s")
    readiness.clear(args.ready_file)
    stop = install_stop_handlers()
    init_zenoh_log()
    try:
        config = load_router_config(Path(args.config))
    except ValueError as exc:
        log.error("%s", exc)
        return 2
    try:
        serve(config, stop, args.ready_file)
    except zenoh.ZError as exc:
        log.error("cannot start the router: %s", zenoh_error_text(exc))
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
