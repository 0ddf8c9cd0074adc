"""Decoding at the edge: what a zenoh subscriber receives is size-capped,
decoded in zenoh's callback thread (never on a service's control thread)
and put into one bounded queue, every drop counted.

One :class:`Inbox` per service; one :meth:`Inbox.subscriber` per key::

    inbox = Inbox("controller", capacity=256, limits=LIMITS)
    session.declare_subscriber(keys.flag, inbox.subscriber("flag", lambda b: decode(BlockFlag, b), MAX_BYTES["flag"]))
    ...
    for item in inbox.drain():          # on the control thread: decoded messages only
        handle(item.kind, item.message, item.arrival)

A payload is refused, counted per kind and logged at most once per kind
and reason per ``log_interval_s`` (:class:`RateLimitedLog`) when it is

* larger than the kind's cap (checked on the payload's length, before a
  byte is copied or parsed: a 10 MB "interrupt" costs nothing);
* undecodable (the decoder raised :class:`~protocol.errors.ProtocolError`
  or ``ValueError``);
* refused by the decoder's own check (it returned :data:`REFUSED`, e.g. an
  interrupt from a DSP session other than the paired one);
* over its kind's rate (:class:`Limit`, a token bucket of ``burst``
  messages refilled at ``rate_per_s``), checked before the payload is
  copied or parsed, so a flood of an allowed message costs each dropped
  one a counter increment;
* one too many: the queue is full, or its kind already holds its share of
  the queue (``Limit.queued``), so one kind's flood cannot crowd another
  out (commands never take the places of flags and interrupts); the newest
  is dropped, so a flood costs the consumer at most ``capacity`` items.

A decoder may also return ``None``: the payload was handled in the
callback and nothing is queued (the DSP admits a batch to its block there).
Nothing here knows zenoh beyond ``sample.payload``; :meth:`offer` is the
pure core the callbacks call, with the clock injected, for tests.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Final, NamedTuple

from protocol.errors import ProtocolError

__all__ = ["LIMITS", "MAX_BYTES", "REFUSED", "Inbox", "InboxCounters", "Item", "Limit", "RateLimitedLog", "TokenBucket"]

KIB: Final[int] = 1024
MAX_BYTES: Final[dict[str, int]] = {
    "flag": 2 * KIB,
    "interrupt": 32 * KIB,
    "command": 4 * KIB,
    "test_command": 4 * KIB,
    "config": 4 * KIB,
    "config_ack": 8 * KIB,
    "scenario": 2 * KIB,
    "health": 128 * KIB,
    "status": 4 * KIB,
    "truth": 16 * KIB,
    "event": 8 * KIB,
    "batch": 8 * 1024 * KIB,
}
"""Payload caps by key kind, far above any honest message (an interrupt
with 32 poles is ~6 KiB; a batch of 65536 samples of 4 channels ~2 MiB)."""


MAX_ATTACHMENT: Final[int] = 256
"""Cap of a zenoh attachment (a board id is 32 hex digits)."""


class _Refused:
    def __repr__(self) -> str:
        return "REFUSED"


REFUSED: Final = _Refused()
"""A decoder's answer for a well-formed payload it will not take (counted as ``refused``)."""


@dataclass(frozen=True)
class Limit:
    """How much of one kind an inbox takes: at most ``burst`` at once and
    ``rate_per_s`` sustained (a token bucket), and at most ``queued`` of
    them waiting in the queue (None: the inbox's capacity)."""

    rate_per_s: float
    burst: int
    queued: int | None = None

    def __post_init__(self) -> None:
        if not (self.rate_per_s > 0 and self.burst >= 1 and (self.queued is None or self.queued >= 1)):
            raise ValueError(f"a limit needs rate_per_s > 0, burst >= 1 and queued >= 1 or None, got {self}")


LIMITS: Final[dict[str, Limit]] = {
    "command": Limit(rate_per_s=10.0, burst=10, queued=4),
    "test_command": Limit(rate_per_s=10.0, burst=10, queued=4),
    "config": Limit(rate_per_s=10.0, burst=10, queued=4),
    "scenario": Limit(rate_per_s=10.0, burst=20, queued=20),
}
"""Rates and queue shares of the kinds a person or a tool sends: far above
any honest use (``ralf-hil reconfigure`` sends one command, the controller
forwards it as one configuration change; a scenario is a handful of
commands), far below a flood. Flags, interrupts and batches have none:
only their board may send them (service_kit/access.py) and the pairing
checks refuse any other's."""


class TokenBucket:
    """``burst`` tokens, refilled at ``rate_per_s``; :meth:`take` spends one
    if there is one. Time comes from the caller (pure, for tests)."""

    def __init__(self, rate_per_s: float, burst: int) -> None:
        self.rate_per_s = rate_per_s
        self.burst = float(burst)
        self.tokens = float(burst)
        self.last: float | None = None

    def take(self, now: float) -> bool:
        if self.last is not None and now > self.last:
            self.tokens = min(self.burst, self.tokens + (now - self.last) * self.rate_per_s)
        if self.last is None or now > self.last:
            self.last = now
        if self.tokens >= 1.0:
            self.tokens -= 1.0
            return True
        return False


class Item(NamedTuple):
    kind: str
    message: Any
    arrival: float


@dataclass
class InboxCounters:
    """What came in on one kind, and what became of it."""

    received: int = 0
    queued: int = 0
    handled: int = 0
    oversize: int = 0
    undecodable: int = 0
    refused: int = 0
    dropped_rate: int = 0
    dropped_full: int = 0

    @property
    def dropped(self) -> int:
        return self.oversize + self.undecodable + self.refused + self.dropped_rate + self.dropped_full


class RateLimitedLog:
    """``warning(key, fmt, *args)`` logs the first time a key is seen and then
    at most once per ``interval_s``, telling how many were suppressed."""

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0, clock: Callable[[], float] = time.monotonic) -> None:
        self._log = logger
        self._interval = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def warning(self, key: str, fmt: str, *args: object) -> bool:
        """Log (True) or count as suppressed (False)."""
        now = self._clock()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self._interval:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return False
            self._last[key] = now
            hidden = self._suppressed.pop(key, 0)
        suffix = f" ({hidden} more like it in the last {self._interval:g} s not logged)" if hidden else ""
        self._log.warning(fmt + "%s", *args, suffix)
        return True


@dataclass
class Inbox:
    """A bounded queue of decoded messages fed by zenoh callbacks;
    ``limits``: the rate and queue share of the kinds that have one."""

    name: str
    capacity: int = 256
    log_interval_s: float = 10.0
    clock: Callable[[], float] = time.monotonic
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("service_kit.inbox"))
    limits: Mapping[str, Limit] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._queue: queue.Queue[Item] = queue.Queue(maxsize=self.capacity)
        self._counters: dict[str, InboxCounters] = {}
        self._lock = threading.Lock()
        self._buckets = {kind: TokenBucket(limit.rate_per_s, limit.burst) for kind, limit in self.limits.items()}
        self._waiting: dict[str, int] = {}
        """Items of each limited kind in the queue now."""
        self.log = RateLimitedLog(self.logger, self.log_interval_s, self.clock)

    # -- the edge (zenoh's threads) -------------------------------------------------------
    def subscriber(self, kind: str, decode: Callable[..., Any], max_bytes: int | None = None, with_attachment: bool = False) -> Callable[[Any], None]:
        """A zenoh subscriber callback for ``kind``: cap, decode, queue.
        With ``with_attachment`` the decoder is called as
        ``decode(payload, attachment)`` (``attachment``: bytes or None, at
        most :data:`MAX_ATTACHMENT` bytes), e.g. to check the sender's board id."""
        cap = MAX_BYTES[kind] if max_bytes is None else max_bytes

        def on_sample(sample: Any) -> None:
            if with_attachment:
                self.offer(kind, sample.payload, decode, cap, attachment=sample.attachment, use_attachment=True)
            else:
                self.offer(kind, sample.payload, decode, cap)

        return on_sample

    def offer(
        self,
        kind: str,
        payload: Any,
        decode: Callable[..., Any],
        max_bytes: int,
        attachment: Any = None,
        use_attachment: bool = False,
        arrival: float | None = None,
    ) -> bool:
        """Cap, decode and queue one payload (anything with ``len`` and
        ``to_bytes()``, or bytes); True if it was queued or handled.
        ``arrival``: when it came, on the caller's clock (default: ``clock()``)."""
        arrival = self.clock() if arrival is None else arrival
        counters = self._count(kind)
        if not self._within_rate(kind, counters, arrival):
            return False
        size = len(payload) + (len(attachment) if attachment is not None else 0)
        if size > max_bytes or (attachment is not None and len(attachment) > MAX_ATTACHMENT):
            with self._lock:
                counters.oversize += 1
            self.log.warning(f"{kind}:oversize", "%s: dropped a %d-byte %s (cap %d bytes)", self.name, size, kind, max_bytes)
            return False
        raw = payload if isinstance(payload, (bytes, bytearray, memoryview)) else payload.to_bytes()
        try:
            if use_attachment:
                extra = None if attachment is None else bytes(attachment if isinstance(attachment, (bytes, bytearray, memoryview)) else attachment.to_bytes())
                message = decode(bytes(raw), extra)
            else:
                message = decode(bytes(raw))
        except (ProtocolError, ValueError) as exc:
            with self._lock:
                counters.undecodable += 1
            self.log.warning(f"{kind}:undecodable", "%s: dropped an invalid %s: %s", self.name, kind, exc)
            return False
        if message is REFUSED:
            with self._lock:
                counters.refused += 1
            self.log.warning(
                f"{kind}:refused", "%s: refused a %s (its receiver's check: another board, a batch never sent, a field its key does not take)", self.name, kind
            )
            return False
        if message is None:
            with self._lock:
                counters.handled += 1
            return True
        return self._put(counters, kind, message, arrival)

    def put(self, kind: str, message: Any, arrival: float | None = None) -> bool:
        """Queue an already decoded message (e.g. a liveliness change)."""
        arrival = self.clock() if arrival is None else arrival
        counters = self._count(kind)
        return self._within_rate(kind, counters, arrival) and self._put(counters, kind, message, arrival)

    def _within_rate(self, kind: str, counters: InboxCounters, now: float) -> bool:
        bucket = self._buckets.get(kind)
        if bucket is None:
            return True
        with self._lock:
            taken = bucket.take(now)
            if not taken:
                counters.dropped_rate += 1
        if not taken:
            limit = self.limits[kind]
            self.log.warning(f"{kind}:rate", "%s: over %g %s a second (burst %d): dropped one", self.name, limit.rate_per_s, kind, limit.burst)
        return taken

    def _put(self, counters: InboxCounters, kind: str, message: Any, arrival: float) -> bool:
        limit = self.limits.get(kind)
        share = limit.queued if limit is not None else None
        with self._lock:
            full = share is not None and self._waiting.get(kind, 0) >= share
            if not full:
                try:
                    self._queue.put_nowait(Item(kind, message, arrival))
                except queue.Full:
                    full = True
            if full:
                counters.dropped_full += 1
            else:
                counters.queued += 1
                if share is not None:
                    self._waiting[kind] = self._waiting.get(kind, 0) + 1
        if full:
            self.log.warning(f"{kind}:full", "%s: inbox full (%d items, or this kind's share): dropped a %s", self.name, self.capacity, kind)
            return False
        return True

    def refuse(self, kind: str, reason: str) -> None:
        """Count (and rate-limit the log of) a message refused after decoding."""
        counters = self._count(kind)
        with self._lock:
            counters.refused += 1
        self.log.warning(f"{kind}:refused", "%s: refused a %s: %s", self.name, kind, reason)

    def _count(self, kind: str) -> InboxCounters:
        with self._lock:
            counters = self._counters.get(kind)
            if counters is None:
                counters = self._counters[kind] = InboxCounters()
            counters.received += 1
            return counters

    # -- the consumer (the service's own thread) -------------------------------------------
    def get(self, timeout: float | None = None) -> Item | None:
        """The next item, waiting up to ``timeout`` (None: forever); None if none came."""
        try:
            return self._taken(self._queue.get(timeout=timeout))
        except queue.Empty:
            return None

    def get_nowait(self) -> Item | None:
        try:
            return self._taken(self._queue.get_nowait())
        except queue.Empty:
            return None

    def _taken(self, item: Item) -> Item:
        if item.kind in self._waiting:
            with self._lock:
                self._waiting[item.kind] -= 1
        return item

    def drain(self, limit: int | None = None) -> list[Item]:
        """Every queued item (at most ``limit``), without waiting."""
        out: list[Item] = []
        while limit is None or len(out) < limit:
            item = self.get_nowait()
            if item is None:
                break
            out.append(item)
        return out

    def __len__(self) -> int:
        # queue.Queue.qsize() is len() of its deque under the queue's lock; a loop asks
        # this every tick, and a deque's length is read whole under the GIL: no lock.
        return len(self._queue.queue)

    # -- reporting ------------------------------------------------------------------------
    def counters(self, kind: str) -> InboxCounters:
        with self._lock:
            return InboxCounters(**vars(self._counters.get(kind, InboxCounters())))

    def as_dict(self) -> dict[str, int]:
        """Flat counters for a health message: ``in_<kind>_<what>`` for every
        non-zero drop, plus ``in_dropped`` (all kinds)."""
        out: dict[str, int] = {}
        total = 0
        with self._lock:
            for kind, c in sorted(self._counters.items()):
                for what in ("oversize", "undecodable", "refused", "dropped_rate", "dropped_full"):
                    n = getattr(c, what)
                    total += n
                    if n:
                        out[f"in_{kind}_{what}"] = n
        out["in_dropped"] = total
        return out
