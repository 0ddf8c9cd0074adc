"""``ralf-hil param list|get|set``: the run-time parameters of a running rig
(docs/calibration.md).

A parameter is ``BOARD.NAME``: the controller's (``controller.kp1``) or the
plant's (``plant.payload``); each board answers on its own keys
(``BOARD/params``, ``BOARD/param_set``, ...). ``list [BOARD]`` (default: the
controller) and ``get`` query the board's parameter table: name, unit, limits
and the value in effect. ``set`` publishes a
:class:`~protocol.messages.ParamSet` on its role's key (``BOARD/param_set``
for the tester, ``BOARD/param_set_tool`` for a tool: the session's
``zenoh_user``; none counts as a tool) and waits for the board's answer:
taken (at the step it names, exit 0) or refused with the reason in one line
(exit 1: a role the run does not let write, a value outside the parameter's
limits, the board's guards). Nothing is changed by a refused set. The
request is resent until an answer arrives (the session may take a moment to
find the board); the board takes a request id once.

A board answers only with its ``param_commands=true``
(``controller.param_commands``, ``plant.param_commands``); without it (or
without the rig's credentials) the command hears nothing and exits 1 saying
so.
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
import uuid
from typing import Any

__all__ = ["add_param_parser", "cmd_param", "query_table", "send_set"]


def add_param_parser(sub: Any) -> None:
    """The ``param`` sub-command."""
    p = sub.add_parser("param", help="list, read or change the run-time parameters of a running rig (BOARD.param_commands=true)")
    p.add_argument("action", choices=("list", "get", "set"), help="list [BOARD] (default: controller); get NAME; set NAME VALUE")
    p.add_argument("name", nargs="?", help="the parameter, BOARD.NAME (controller.kp1, plant.payload); list: the board")
    p.add_argument("value", nargs="?", help="set: the physical value, in the parameter's unit (ralf-hil param list)")
    p.add_argument("--rig-id", default=None, help="the rig's id (default: RALF_RIG_ID, else default)")
    p.add_argument("--connect", default="", help="zenoh endpoint(s) of the rig (tool.env and tester.env set RALF_ZENOH_CONNECT)")
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the board's answer (default: 5)")
    p.set_defaults(func=cmd_param)


def _fail(text: str, code: int = 1) -> int:
    print(f"ralf-hil param: {text}", file=sys.stderr)
    return code


BOARDS = ("controller", "plant")
"""The boards that serve parameters (``workbench.params.PARAM_TABLES``)."""


def _arguments(args: argparse.Namespace) -> tuple[str, str | None, float | None] | str:
    """``(board, name, value)`` for the action, or what is wrong with them."""
    if args.action == "list":
        board = args.name if args.name is not None else "controller"
        if board not in BOARDS or args.value is not None:
            return f"list takes a board ({', '.join(BOARDS)}), not {' '.join(x for x in (args.name, args.value) if x is not None)!r}"
        return board, None, None
    if args.name is None:
        return f"{args.action} needs a parameter name (ralf-hil param list names them)"
    board = args.name.partition(".")[0]
    if board not in BOARDS:
        return f"{args.name!r}: no board {board!r} serves parameters ({', '.join(BOARDS)}: BOARD.NAME)"
    if args.action == "get":
        return (board, args.name, None) if args.value is None else "get takes a name only"
    if args.value is None:
        return "set needs a value"
    try:
        value = float(args.value)
    except ValueError:
        return f"{args.value!r} is not a number"
    if not math.isfinite(value):
        return f"{args.value!r} is not a finite number"
    return board, args.name, value


def _limits(info: Any) -> str:
    return f"{info.lower:g} .. {info.upper:g}"


def _value(info: Any) -> str:
    return "-" if info.value is None else f"{info.value:.10g}"


def cmd_param(args: argparse.Namespace) -> int:
    from protocol.errors import ConfigError
    from protocol.keys import Keys, param_keys
    from protocol.settings import CommonSettings, load_settings
    from service_kit.transport import TransportError, open_zenoh
    from workbench import monitor

    parsed = _arguments(args)
    if isinstance(parsed, str):
        return _fail(parsed, 2)
    board, name, value = parsed
    if not args.timeout > 0:
        return _fail(f"--timeout must be positive, got {args.timeout}", 2)
    overrides = {"rig_id": args.rig_id} if args.rig_id is not None else {}
    if args.connect:
        overrides["zenoh_connect"] = args.connect
    try:
        settings = load_settings(CommonSettings, overrides)
        session = open_zenoh(settings, retry_for_s=0.0)
    except (ConfigError, TransportError) as exc:
        return _fail(" ".join(str(exc).split()), 2)
    keys = param_keys(Keys(settings.rig_id), board)
    role = settings.zenoh_user if settings.zenoh_user in ("tester", "tool") else "tool"
    silent = (
        f"no answer from the {board} of rig {settings.rig_id!r} within {args.timeout:g} s "
        f"(it answers only with {board}.param_commands=true; this session's user: {settings.zenoh_user or '(none)'})"
        f"{monitor.credentials_hint(settings)}"
    )
    try:
        if args.action == "set":
            assert name is not None and value is not None
            answer = send_set(session, keys, role, name, value, args.timeout)
            if answer is None:
                return _fail(f"{silent}; {name} not changed")
            if not answer.accepted:
                return _fail(f"refused: {answer.reason}")
            print(f"{answer.name} = {answer.value:.10g} on rig {settings.rig_id!r} from {answer.sim_time_s:.3f} s (role {role})")
            return 0
        table = query_table(session, keys, args.timeout)
    finally:
        session.close()
    if table is None:
        return _fail(silent)
    if args.action == "get":
        info = next((p for p in table.params if p.name == name), None)
        if info is None:
            return _fail(f"no parameter {name!r} (known: {', '.join(p.name for p in table.params)})")
        print(f"{info.name} = {_value(info)} {info.unit}".rstrip() + f" (limits {_limits(info)})")
        return 0
    width = max((len(p.name) for p in table.params), default=4)
    print(f"{'name':<{width}}  {'unit':<7} {'limits':<20} value")
    for p in table.params:
        print(f"{p.name:<{width}}  {p.unit or '-':<7} {_limits(p):<20} {_value(p)}")
    print(f"changes taken from: {', '.join(table.write_roles) or 'no role'}")
    return 0


def query_table(session: Any, keys: Any, timeout_s: float) -> Any:
    """A board's :class:`~protocol.messages.ParamTable` (``keys``: :class:`~protocol.keys.Keys` for the controller's, or
    a board's :class:`~protocol.keys.ParamKeys`), or None if nothing answered within ``timeout_s``."""
    from protocol.errors import ProtocolError
    from protocol.messages import ParamTable, decode

    deadline = time.monotonic() + timeout_s
    while True:  # retried: the session may take a moment to find the board
        left = deadline - time.monotonic()
        for reply in session.get(keys.params, timeout=max(0.1, min(1.0, left))):
            if reply.ok is not None:
                try:
                    return decode(ParamTable, reply.ok.payload.to_bytes())
                except ProtocolError:
                    continue
        if time.monotonic() >= deadline:
            return None


def send_set(session: Any, keys: Any, role: str, name: str, value: float, timeout_s: float) -> Any:
    """Publish ``name = value`` on ``role``'s key until the board's :class:`~protocol.messages.ParamAnswer`
    to it arrives (None after ``timeout_s``; ``keys`` as :func:`query_table` takes them)."""
    from protocol.errors import ProtocolError
    from protocol.messages import ParamAnswer, ParamSet, decode, encode
    from service_kit.encodings import JSON

    request_id = uuid.uuid4().hex[:16]
    got: list[Any] = []
    answered = threading.Event()

    def on_answer(sample: Any) -> None:
        try:
            answer = decode(ParamAnswer, sample.payload.to_bytes())
        except ProtocolError:
            return
        if answer.request_id == request_id:
            got.append(answer)
            answered.set()

    key = keys.param_set if role == "tester" else keys.param_set_tool
    cmd = encode(ParamSet(seq=0, sim_time_s=0.0, request_id=request_id, name=name, value=value))
    sub = session.declare_subscriber(keys.param_answer, on_answer)
    try:
        deadline = time.monotonic() + timeout_s
        while not answered.is_set() and time.monotonic() < deadline:
            session.put(key, cmd, encoding=JSON)
            answered.wait(min(0.5, max(0.0, deadline - time.monotonic())))
    finally:
        sub.undeclare()
    return got[0] if got else None
