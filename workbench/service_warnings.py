"""The rig's own warnings during a tool's in-process runs, counted instead of printed.

A co-simulated or one-process rig runs the services' classes inside the
tool, and their log warnings (``stale: parameters stale at tick ...``, a
monitor firing; ``deadline: batch ...: compute ... over budget``, the DSP's
budget) would reach the terminal as bare lines through Python's last-resort
handler, with no context, in runs that end fine. Inside
:func:`counted_warnings` they are not printed: each is counted by its kind
(the word before the first colon, else the logger) with its first message kept, and the
caller reports them (an experiment's report, ``results.json`` and its
closing line). Runs on Dask workers count theirs in the worker
(:mod:`workbench.campaign.engine`) and the counts come back with the result
(:func:`add_remote`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

RIG_LOGGERS = ("controller", "dsp_service", "plant_emulator", "service_kit", "protocol", "readiness", "zenoh")
"""Top-level names of the loggers the rig's classes log to (``zenoh``: zenoh's own lines, as the services forward them)."""


def kind_of(message: str, logger: str) -> str:
    """A warning's kind: the word before its first colon (``stale``, ``deadline``), else the logger's name."""
    head, sep, _ = message.partition(":")
    head = head.strip()
    return head if sep and head and " " not in head and len(head) <= 32 else logger


@dataclass
class WarningTally:
    """Warnings counted by kind, the first message of each kept."""

    counts: dict[str, int] = field(default_factory=dict)
    first: dict[str, str] = field(default_factory=dict)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, kind: str, message: str, count: int = 1) -> None:
        with self._lock:
            self.counts[kind] = self.counts.get(kind, 0) + count
            self.first.setdefault(kind, message)

    def merge(self, other: dict[str, Any]) -> None:
        """Counts from :meth:`as_dict` (a worker's)."""
        for kind, entry in other.items():
            self.add(kind, str(entry["first"]), int(entry["count"]))

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def as_dict(self) -> dict[str, dict[str, Any]]:
        with self._lock:
            return {kind: {"count": n, "first": self.first[kind]} for kind, n in sorted(self.counts.items())}

    def line(self) -> str:
        """``stale ×31, deadline ×4`` ('' when none)."""
        return ", ".join(f"{kind} ×{entry['count']}" for kind, entry in self.as_dict().items())


class _Counter(logging.Handler):
    def __init__(self, tally: WarningTally) -> None:
        super().__init__(logging.WARNING)
        self.tally = tally

    def emit(self, record: logging.LogRecord) -> None:
        if record.name.split(".")[0] not in RIG_LOGGERS:
            return
        try:
            message = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad format: counted by its template
            message = str(record.msg)
        self.tally.add(kind_of(message, record.name), " ".join(message.split()))


_active: list[WarningTally] = []
_active_lock = threading.Lock()


@contextmanager
def counted_warnings() -> Iterator[WarningTally]:
    """While the block runs, the rig's warnings in this process are counted
    in the yielded tally, and not printed by Python's last-resort handler
    (a handler on the rig's loggers takes them; loggers the caller configured
    still get them)."""
    tally = WarningTally()
    handler = _Counter(tally)
    loggers = [logging.getLogger(name) for name in RIG_LOGGERS]
    for lg in loggers:
        lg.addHandler(handler)
    with _active_lock:
        _active.append(tally)
    try:
        yield tally
    finally:
        with _active_lock:
            _active.remove(tally)
        for lg in loggers:
            lg.removeHandler(handler)


def add_remote(counts: dict[str, Any]) -> None:
    """Counts from a run in another process, added to the innermost :func:`counted_warnings` of this one."""
    with _active_lock:
        tally = _active[-1] if _active else None
    if tally is not None and counts:
        tally.merge(counts)
