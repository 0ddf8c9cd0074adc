"""Rate limits and counts of the queries a service answers, like
:mod:`service_kit.inbox`'s of the messages it takes in.

An answer can cost far more than its query (a TF snapshot is tens of
kilobytes, computed under the identifier's lock), and any session that may
query the key (the controller, and every tool: service_kit/access.py) can
send as many as it likes. A :class:`QueryGate` per queryable lets through
at most ``burst`` queries at once and ``rate_per_s`` sustained (a
:class:`~service_kit.inbox.TokenBucket`); a query over the rate gets a
short error reply at once (the querier learns why, and waits for nothing)
and is counted, logged at most once per ``log_interval_s``. Its counters go
into the service's health as ``q_<kind>_answered``, ``q_<kind>_failed``
and ``q_<kind>_dropped_rate``.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Final

from service_kit.inbox import Limit, RateLimitedLog, TokenBucket

QUERY_LIMITS: Final[dict[str, Limit]] = {
    "tf": Limit(rate_per_s=20.0, burst=20),
    "params": Limit(rate_per_s=20.0, burst=20),
}
"""Per query kind: far above honest use (the controller downloads the TF every
``tf_download_samples`` samples, 5 s at the defaults; a viewer a few a
second), far below a flood."""

OVER_RATE: Final[bytes] = b"over the query rate: refused"
"""The error reply to a query over its kind's rate."""


@dataclass
class QueryGate:
    """Admits, counts and refuses the queries of one kind (module docstring)."""

    kind: str
    limit: Limit
    clock: Callable[[], float] = time.monotonic
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("service_kit.query_gate"))
    log_interval_s: float = 10.0
    answered: int = 0
    failed: int = 0
    dropped_rate: int = 0

    def __post_init__(self) -> None:
        self._bucket = TokenBucket(self.limit.rate_per_s, self.limit.burst)
        self._lock = threading.Lock()
        self._log = RateLimitedLog(self.logger, self.log_interval_s, self.clock)

    def admit(self) -> bool:
        """True: answer this query (then :meth:`note_answered` or :meth:`note_failed`);
        False: it is over the rate, counted; reply :data:`OVER_RATE` as an error."""
        with self._lock:
            if self._bucket.take(self.clock()):
                return True
            self.dropped_rate += 1
        self._log.warning(f"{self.kind}:rate", "over %g %s queries a second (burst %d): refused one", self.limit.rate_per_s, self.kind, self.limit.burst)
        return False

    def note_answered(self) -> None:
        with self._lock:
            self.answered += 1

    def note_failed(self) -> None:
        with self._lock:
            self.failed += 1

    def as_dict(self) -> dict[str, int]:
        """Counters for a health message."""
        with self._lock:
            return {f"q_{self.kind}_answered": self.answered, f"q_{self.kind}_failed": self.failed, f"q_{self.kind}_dropped_rate": self.dropped_rate}


def gate(kind: str, clock: Callable[[], float] = time.monotonic) -> QueryGate:
    """The gate of ``kind`` with its limit from :data:`QUERY_LIMITS`."""
    return QueryGate(kind, QUERY_LIMITS[kind], clock)
