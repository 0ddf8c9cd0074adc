"""zenoh's own log (its Rust ``tracing`` events) through the process's
Python logging, at a sane level.

zenoh-python prints its log lines to file descriptor 1 (stdout), raw, with
colour codes and Rust source locations (``zenoh.init_log_from_env_or``).
:func:`init_zenoh_log` starts that log at ``RUST_LOG`` or the given level
(``error``; ``RUST_LOG=warn`` shows zenoh's warnings too), without
colour, and, in a service process (:func:`route_to_logging`), moves
descriptor 1 onto a pipe whose lines a thread hands to ``logging``: zenoh's
as records of the logger ``zenoh.<target>`` at their own level, without
the source location; any other line unchanged to the original stdout,
which Python's own ``sys.stdout`` keeps writing to directly.
"""

from __future__ import annotations

import atexit
import io
import logging
import os
import re
import sys
import threading

import zenoh

DEFAULT_LEVEL = "error"
"""zenoh's level when ``RUST_LOG`` is not set: its errors (its warnings
repeat what the service reports itself, e.g. a listening port in use)."""

_LINE = re.compile(r"^\S+Z\s+(TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:(?:\S+\s+)?ThreadId\(\d+\)\s+)?([\w:]+):\s(.*)$")
_WHERE = re.compile(r"\s+at /\S+?\.rs:\d+\.?$")
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
LEVELS = {"TRACE": logging.DEBUG, "DEBUG": logging.DEBUG, "INFO": logging.INFO, "WARN": logging.WARNING, "ERROR": logging.ERROR}

ROUTINE = ("Scouting delay elapsed before start conditions are met",)
"""zenoh warnings that are a normal start, logged at INFO: a peer whose
connect endpoints are not all listening yet when it opens (services started
one by one) keeps retrying them in the background."""

_started = False
_lock = threading.Lock()


def parse_line(line: str) -> tuple[int, str, str] | None:
    """(logging level, logger name, message) of one zenoh log line; None for any other line."""
    m = _LINE.match(_ANSI.sub("", line.rstrip("\n")))
    if m is None:
        return None
    message = _WHERE.sub("", m[3])
    level = logging.INFO if m[1] == "WARN" and message.startswith(ROUTINE) else LEVELS[m[1]]
    return level, f"zenoh.{m[2].split('::', 1)[0]}", message


def init_zenoh_log(level: str = DEFAULT_LEVEL) -> None:
    """Start zenoh's log once per process, at ``RUST_LOG`` or ``level``, without colour codes."""
    global _started
    with _lock:
        if _started:
            return
        _started = True
        before = os.environ.get("NO_COLOR")
        os.environ["NO_COLOR"] = "1"  # read by zenoh's log formatter when it starts
        try:
            zenoh.init_log_from_env_or(level)
        finally:
            if before is None:
                del os.environ["NO_COLOR"]
            else:
                os.environ["NO_COLOR"] = before


def _forward(read_fd: int, out: io.TextIOBase) -> None:
    with os.fdopen(read_fd, "r", errors="replace") as pipe:
        for line in pipe:
            parsed = parse_line(line)
            if parsed is None:
                out.write(line)
                out.flush()
                continue
            level, name, message = parsed
            logging.getLogger(name).log(level, "%s", message)


def route_to_logging(level: str = DEFAULT_LEVEL) -> bool:
    """In a service process: zenoh's log lines become logging records (see
    the module's text). Returns False (zenoh's log left on stdout, still
    without colour) where stdout is not this process's own descriptor 1 (a
    test runner capturing it)."""
    stdout = sys.stdout
    try:
        own = isinstance(stdout, io.TextIOWrapper) and stdout.fileno() == 1
    except (OSError, ValueError):
        own = False
    if not own:
        init_zenoh_log(level)
        return False
    stdout.flush()
    saved = os.dup(1)
    read_fd, write_fd = os.pipe()
    os.dup2(write_fd, 1)
    os.close(write_fd)
    sys.stdout = io.TextIOWrapper(os.fdopen(saved, "wb", buffering=0), encoding=stdout.encoding, errors=stdout.errors, line_buffering=True)
    thread = threading.Thread(target=_forward, args=(read_fd, sys.stdout), name="zenoh-log", daemon=True)
    thread.start()

    def drain() -> None:
        os.dup2(saved, 1)  # the pipe's last writer closed: the thread reads to its end
        thread.join(timeout=1.0)

    atexit.register(drain)
    init_zenoh_log(level)
    return True
