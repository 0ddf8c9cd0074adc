"""Opening the two transports from settings: a zenoh session and a python-can
bus. The interface is a setting, never a code change (docs/design.md)."""

from __future__ import annotations

import json
import logging
import re
import socket
import threading
import time
from typing import Any

import can
import zenoh

from protocol.errors import TransportError
from protocol.settings import CommonSettings
from service_kit.access import insert_access
from service_kit.can_udp import LoopFreeUdpMulticastBus
from service_kit.zenoh_log import init_zenoh_log

log = logging.getLogger(__name__)


PEER_AUTOCONNECT_STRATEGY = '{peer: {to_router: "always", to_peer: "greater-zid"}}'
"""``scouting/gossip/autoconnect_strategy``: of two peers, the one with the greater id connects."""

OPENER_AUTOCONNECT_STRATEGY = '{peer: {to_router: "always", to_peer: "always"}}'
"""The strategy of a peer that listens on nothing (a tool): it connects to every peer it learns of."""


def zenoh_config(settings: CommonSettings) -> zenoh.Config:
    """A zenoh configuration from settings (mode, endpoints, scouting)."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(settings.zenoh_mode))
    config.insert_json5("scouting/multicast/enabled", json.dumps(settings.zenoh_multicast_scouting))
    config.insert_json5("transport/link/tx/lease", json.dumps(settings.zenoh_lease_ms))
    # No shared-memory transport: zenoh would move payloads over 3 KB (a
    # batch, a TF snapshot) through a 16 MiB pool, which it creates at the
    # first such put and maps with mlock (every page faulted in while the
    # process's mmap lock is held: 12-19 ms in the controller at its first
    # batch, the loop blocked in the kernel meanwhile; ~30 ms in the DSP at its
    # first TF snapshot; the peer pays again when it first maps the pool), and
    # runs two watchdog threads per process at 20 and 10 Hz. Over loopback TCP
    # a 6 KB batch or a 91 KB snapshot costs zenoh's I/O threads a copy, not
    # the loop (docs/timing.md, "What a first batch cost").
    config.insert_json5("transport/shared_memory/enabled", "false")
    # Peers that learn of each other by gossip link once: only the one with the
    # greater zenoh id connects (zenoh's default lets both try at once, and
    # one link of the pair is refused with an ERROR on each side).
    config.insert_json5("scouting/gossip/autoconnect_strategy", PEER_AUTOCONNECT_STRATEGY)
    listen = settings.endpoints("listen")
    # A node's own listening endpoint in its connect list (one list shared by
    # services started one by one) is a link to itself, refused by zenoh
    # with CONNECTION_TO_SELF at every retry: dropped.
    connect = [e for e in settings.endpoints("connect") if e not in listen]
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    tls = settings.zenoh_tls()
    if not listen and settings.zenoh_mode == "peer" and (tls is not None or not settings.zenoh_multicast_scouting):
        # A peer given no endpoint to listen on listens on none (zenoh's own
        # default is tcp/[::]:0: a plain-TCP listener on every interface, which a
        # node of the rig would then link to without the rig's TLS) and opens its
        # links itself, to every peer gossip names, whichever id is the greater:
        # no peer can open a link to it, so a pair still links once. (Peers that
        # find each other by multicast scouting without TLS keep zenoh's
        # listener: two of them with none could not link.)
        config.insert_json5("listen/endpoints", "[]")
        config.insert_json5("scouting/gossip/autoconnect_strategy", OPENER_AUTOCONNECT_STRATEGY)
    # No zenoh ``downsampling`` on the keys tools send: what it drops it does
    # not count (its stats are not built into the Python wheel: the admin
    # space's ``@/<zid>/<mode>/metrics`` holds only the build), so every
    # command and scenario command reaches the service's inbox, which takes
    # them at its rate and counts the rest (service_kit/inbox.py, ``LIMITS``).
    insert_access(
        config,
        settings.rig_id,
        user=settings.zenoh_user,
        password=settings.zenoh_password.get_secret_value(),
        credentials_file=settings.zenoh_credentials_file,
        # A client's one link is the one it opened to its router, which applies the rules.
        acl=settings.zenoh_acl != "off" and settings.zenoh_mode != "client",
        scenarios=settings.zenoh_acl == "scenarios",
        more_rigs=getattr(settings, "rig_ids", ())[1:],  # a DSP serving several rigs
        tls=tls[0] if tls is not None else None,
        tls_inline=tls is not None and tls[1],
    )
    return config


_RUST_WHERE = re.compile(r"\s+at /\S+?\.rs:\d+\.?")
_NOT_YET = "Unable to connect to any of"
"""The one zenoh error worth waiting out: a client whose router is not up
yet. A bad endpoint, an unsupported protocol or a port already in use fails
at once and for good."""


def zenoh_error_text(exc: BaseException) -> str:
    """zenoh's message on one line, without its Rust source locations."""
    return " ".join(_RUST_WHERE.sub("", str(exc)).split())


def _answering(endpoints: list[str], timeout_s: float = 1.0) -> list[str]:
    """The tcp and tls endpoints among ``endpoints`` that accept a TCP connection."""
    up = []
    for endpoint in endpoints:
        m = re.fullmatch(r"(?:tcp|tls)/\[?([^\]]+?)\]?:(\d+)(?:[?#].*)?", endpoint)
        if m is None:
            continue
        try:
            with socket.create_connection((m[1], int(m[2])), timeout=timeout_s):
                up.append(endpoint)
        except OSError:
            pass
    return up


RETRY_LOG_EVERY_S = 10.0
"""While waiting for its router, a client says so at the first try and then this often."""


def open_zenoh(settings: CommonSettings, retry_for_s: float = 30.0, sleep: Any = time.sleep, stop: threading.Event | None = None) -> zenoh.Session:
    """Open a zenoh session; a client retries while its router starts (only
    that: any other failure raises :class:`TransportError` at once). It logs
    one line at the first failed try and one every :data:`RETRY_LOG_EVERY_S`;
    the line says whether the router answers at all: one that accepts the
    connection but refuses the session refused the credentials (or is not a
    zenoh router). ``stop`` (SIGTERM) ends the wait with a TransportError."""
    init_zenoh_log()  # once per process; a service has routed it to logging before (service_kit.zenoh_log)
    started = time.monotonic()
    deadline = started + retry_for_s
    next_line = started
    where = f"mode {settings.zenoh_mode}, connect {settings.zenoh_connect or '-'}, listen {settings.zenoh_listen or '-'}"
    while True:
        try:
            return zenoh.open(zenoh_config(settings))
        except zenoh.ZError as exc:
            text = zenoh_error_text(exc)
            if _NOT_YET not in text:
                raise TransportError(f"cannot open zenoh session ({where}): {text}") from None
            answering = _answering(settings.endpoints("connect"))
            if answering:
                tls = settings.zenoh_tls() is not None
                who = f"mutual TLS, user {settings.zenoh_user or '-'}" if tls else f"user {settings.zenoh_user or '-'}"
                why = (
                    "a certificate of another run's authority (this session's or the other end's), or a wrong password?"
                    if tls
                    else "wrong password or unknown user?"
                )
                text = f"{', '.join(answering)} accepts connections but refused the session ({who}): {why}"
            if time.monotonic() >= deadline:
                what = "refused" if answering else "nothing answered"
                raise TransportError(f"cannot open zenoh session ({where}): {what} for {retry_for_s:.0f} s: {text}") from None
            if stop is not None and stop.is_set():
                raise TransportError(f"cannot open zenoh session ({where}): stopped while waiting: {text}") from None
            if time.monotonic() >= next_line:
                log.warning("zenoh router not reachable yet (%s); retrying for up to %.0f s", text, max(0.0, deadline - time.monotonic()))
                next_line = time.monotonic() + RETRY_LOG_EVERY_S
            if stop is not None:
                stop.wait(0.5)
            else:
                sleep(0.5)


WIRE_COSIM_ONLY = (
    "RALF_CAN_BITRATE={bitrate}: a bus of one service alone carries frames in no wire time; the wire is simulated "
    "in co-simulation and the one-process lockstep rig, and ralf-hil up --can-bitrate puts the processes on a wire arbiter (set 0)"
)
WIRE_INTERFACES = ("ralfhub", "ralfwire")
"""Interfaces that give frames their wire time themselves (the arbiter, the in-process wire)."""


FILTERING_INTERFACES = ("ralfhub",)
"""Interfaces whose acceptance filters run outside the process (the wire arbiter's, as a CAN
controller's in hardware): there a service sets filters for the frames it consumes."""


def open_can_bus(settings: CommonSettings, consumes: can.typechecking.CanFilters | None = None, **kwargs: Any) -> can.BusABC:
    """Open the CAN bus named by the settings (udp_multicast, virtual,
    socketcan...). udp_multicast frames get the TTL ``can_udp``'s ``ttl``:
    0 (the default) keeps them on this host. With its ``own_frame_filter``
    (the default) udp_multicast is :class:`service_kit.can_udp.LoopFreeUdpMulticastBus`,
    wire-compatible with python-can's, which does not read its own frames back.
    ``consumes``: python-can filters for every frame the service reads; set
    as the bus's acceptance filters on :data:`FILTERING_INTERFACES`, where the
    frames they refuse never reach the process; elsewhere the bus hands over
    every frame, as without them."""
    if settings.can_bitrate and settings.can_interface not in WIRE_INTERFACES:
        raise TransportError(WIRE_COSIM_ONLY.format(bitrate=settings.can_bitrate))
    options: dict[str, Any] = {"interface": settings.can_interface, "channel": settings.can_channel}
    if consumes and settings.can_interface in FILTERING_INTERFACES:
        options["can_filters"] = list(consumes)
    if settings.can_interface == "udp_multicast":
        options["port"] = settings.can_port
        options["hop_limit"] = settings.can_udp.ttl
    options.update(kwargs)
    try:
        if settings.can_interface == "udp_multicast" and settings.can_udp.own_frame_filter:
            del options["interface"]
            return LoopFreeUdpMulticastBus(**options)
        return can.Bus(**options)
    except Exception as exc:  # python-can raises several types by interface
        detail = " ".join(str(exc).split()) or type(exc).__name__
        raise TransportError(f"cannot open CAN bus {settings.can_interface}:{settings.can_channel}: {detail}") from None
