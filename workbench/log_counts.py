"""WARNING and ERROR lines per service: counted in a service's log file
(``ralf-hil up``'s processes) or as they are logged (a co-simulation, every
board in this process), for the run's verdict (:mod:`workbench.verdict`)."""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

SERVICE_OF_LOGGER: Mapping[str, str] = {"controller": "controller", "plant_emulator": "plant", "dsp_service": "dsp"}
"""A logger's top-level package -> the service it belongs to (any other logger: ``rig``)."""


def count_log_lines(text: str) -> tuple[int, int]:
    """(WARNING, ERROR-or-worse) lines of a service's log (``service_kit.runtime``'s
    format: ``DATE TIME SERVICE LEVEL LOGGER: message``)."""
    warnings = errors = 0
    for line in text.splitlines():
        parts = line.split(" ", 4)
        if len(parts) < 5:
            continue
        if parts[3] == "WARNING":
            warnings += 1
        elif parts[3] in ("ERROR", "CRITICAL"):
            errors += 1
    return warnings, errors


def count_log_files(logs: Mapping[str, Path]) -> tuple[dict[str, int], dict[str, int]]:
    """WARNING and ERROR-or-worse lines in each service's log (a missing log: not counted)."""
    warnings, errors = {}, {}
    for name, path in logs.items():
        try:
            warnings[name], errors[name] = count_log_lines(path.read_text(errors="replace"))
        except OSError:
            continue
    return warnings, errors


class _Counting(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.warnings: Counter[str] = Counter()
        self.errors: Counter[str] = Counter()

    def emit(self, record: logging.LogRecord) -> None:
        service = SERVICE_OF_LOGGER.get(record.name.split(".", 1)[0], "rig")
        (self.warnings if record.levelno < logging.ERROR else self.errors)[service] += 1


@contextmanager
def counting_warnings() -> Iterator[tuple[Counter[str], Counter[str]]]:
    """Count the WARNING and ERROR-or-worse records logged in this process while
    inside, per service; yields the two counters (filled as records come)."""
    handler = _Counting()
    root = logging.getLogger()
    # A handler on the root switches logging's last resort off: where nothing
    # else prints the records, one that prints them as it would stands in.
    shown = None if root.handlers else logging.StreamHandler()
    if shown is not None:
        shown.setLevel(logging.WARNING)
        root.addHandler(shown)
    root.addHandler(handler)
    try:
        yield handler.warnings, handler.errors
    finally:
        root.removeHandler(handler)
        if shown is not None:
            root.removeHandler(shown)
