"""``ralf-hil fault``: a channel fault inserted into a running rig's plant.

The fault (:func:`workbench.fiu.build_fault`, checked at once: a bad one is
one line, exit 2) goes out on the plant's test port as a ``channel_fault``
scenario command, resent until the plant tells, as a plant event, that it
took it (``channel_fault_added``: exit 0) or could not apply it
(``channel_fault_refused``: exit 1). The plant takes a resent command once.

Only the ``tester`` role may send scenario commands, and only to a rig that
accepts them (``ralf-hil up --scenarios``, or ``ralf-hil credentials
--scenarios`` for compose): the rig's access rules (service_kit/access.py)
drop anything else's, so with the tool's credentials the command hears
nothing and exits 1 naming the role.
"""

from __future__ import annotations

import argparse
import random
import sys
import threading
import time
from typing import Any

from protocol.channel_faults import AD_KINDS, DA_KINDS
from workbench.fiu import FaultError, build_fault, channel_fault_command

__all__ = ["add_fault_parser", "cmd_fault"]

KINDS = tuple(dict.fromkeys((*AD_KINDS, *DA_KINDS)))
PARAMETERS: tuple[tuple[str, type, str], ...] = (
    ("value_v", float, "open/stuck/intermittent: the value read (V); short_supply: the rail"),
    ("offset_v", float, "offset: volts added"),
    ("factor", float, "gain: the factor"),
    ("sigma_v", float, "noise: its standard deviation (V)"),
    ("seed", int, "noise: its generator's seed"),
    ("rate_v_s", float, "drift: V/s"),
    ("period_s", float, "intermittent: its period (s)"),
    ("duty", float, "intermittent: the fraction of each period connected"),
    ("bits", int, "lost_bits: how many low bits read 0"),
    ("samples", int, "delay: how many samples late"),
    ("other", str, "short_channels: the other input"),
    ("limit_v", float, "saturate: the valve's limit (V)"),
)


def add_fault_parser(sub: Any) -> None:
    """The ``fault`` sub-command."""
    p = sub.add_parser("fault", help="insert a fault on a channel of a running rig's plant (tester role; ralf-hil up --scenarios)")
    p.add_argument("kind", choices=KINDS, help="the fault (docs/fault-insertion.md)")
    p.add_argument("channel", help="AI1..AI4 (A/D inputs) or AO1, AO2 (valves)")
    p.add_argument("--at", type=float, default=0.0, metavar="S", help="simulated time it starts (default 0: at once)")
    p.add_argument("--for", dest="for_s", type=float, default=None, metavar="S", help="how long it lasts (default: to the end of the run)")
    for name, kind, text in PARAMETERS:
        p.add_argument("--" + name.replace("_", "-"), dest=name, type=kind, default=None, help=text)
    p.add_argument("--rig-id", default=None, help="the rig's id (default: RALF_RIG_ID, else default)")
    p.add_argument("--connect", default="", help="zenoh endpoint(s) of the rig (tester.env sets RALF_ZENOH_CONNECT)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the plant's answer (default: 5)")
    p.set_defaults(func=cmd_fault)


def cmd_fault(args: argparse.Namespace) -> int:
    from protocol.errors import ConfigError
    from protocol.keys import Keys
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import open_zenoh
    from workbench import monitor

    params = {name: getattr(args, name) for name, _, _ in PARAMETERS}
    try:
        fault = build_fault(args.channel, args.kind, args.at, args.for_s, **params)
    except FaultError as exc:
        print(f"ralf-hil fault: {exc}", file=sys.stderr)
        return 2
    if not args.timeout > 0:
        print(f"ralf-hil fault: --timeout must be positive, got {args.timeout}", file=sys.stderr)
        return 2
    overrides = {"rig_id": args.rig_id} if args.rig_id is not None else {}
    if args.connect:
        overrides["zenoh_connect"] = args.connect
    try:
        settings = load_settings(CommonSettings, overrides)
        session = open_zenoh(settings, retry_for_s=0.0)
    except ConfigError as exc:
        print(f"ralf-hil fault: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    try:
        answer = send_fault(session, Keys(settings.rig_id), channel_fault_command(fault, seq=random.randrange(2**31)), args.timeout)
    finally:
        session.close()
    if answer is None:
        role = settings.zenoh_user or "(none)"
        print(
            f"ralf-hil fault: no answer from the plant of rig {settings.rig_id!r} within {args.timeout:g} s; {fault.describe()} not applied "
            f"(scenario commands are taken from the tester role only, on a rig started with --scenarios; this session's user: {role})"
            f"{monitor.credentials_hint(settings)}",
            file=sys.stderr,
        )
        return 1
    kind, detail = answer
    if kind == "channel_fault_refused":
        print(f"ralf-hil fault: the plant refused {detail}", file=sys.stderr)
        return 1
    print(f"inserted on rig {settings.rig_id!r}: {detail}")
    return 0


def send_fault(session: Any, keys: Any, cmd: Any, timeout_s: float) -> tuple[str, str] | None:
    """Publish ``cmd`` on the plant's scenario key until the plant's event about it
    arrives: (event kind, detail), or None after ``timeout_s``."""
    from protocol.errors import ProtocolError
    from protocol.messages import PlantEvent, decode, encode
    from service_kit.encodings import JSON

    described = cmd.channel_fault.describe()
    got: list[tuple[str, str]] = []
    answered = threading.Event()

    def on_event(sample: Any) -> None:
        try:
            event = decode(PlantEvent, sample.payload.to_bytes())
        except ProtocolError:
            return
        if event.kind in ("channel_fault_added", "channel_fault_refused") and event.detail.startswith(described):
            got.append((event.kind, event.detail))
            answered.set()

    sub = session.declare_subscriber(keys.plant_events, on_event)
    try:
        deadline = time.monotonic() + timeout_s
        while not answered.is_set() and time.monotonic() < deadline:  # resent: the session may take a moment to find the plant
            session.put(keys.scenario, encode(cmd), encoding=JSON)
            answered.wait(min(0.5, max(0.0, deadline - time.monotonic())))
    finally:
        sub.undeclare()
    return got[0] if got else None
