"""Decoding at the edge: what a zenoh subscriber receives is size-capped,
decoded in zenoh's callback thread (never on a service's control thread)
and put into one bounded queue, every drop counted.

One :class:`Inbox` per service; one :meth:`Inbox.subscriber` per key::

    inbox = Inbox("controller", capacity=256)
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
* one too many: the queue is full (a flood); the newest is dropped, so a
  flood costs the consumer at most ``capacity`` items.

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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Final, NamedTuple

from protocol.errors import ProtocolError

__all__ = ["MAX_BYTES", "REFUSED", "Inbox", "InboxCounters", "Item", "RateLimitedLog"]

KIB: Final[int] = 1024
MAX_BYTES: Final[dict[str, int]] = {
    "flag": 2 * KIB,
    "interrupt": 32 * KIB,
    "command": 4 * KIB,
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
    dropped_full: int = 0

    @property
    def dropped(self) -> int:
        return self.oversize + self.undecodable + self.refused + self.dropped_full


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
    """A bounded queue of decoded messages fed by zenoh callbacks."""

    name: str
    capacity: int = 256
    log_interval_s: float = 10.0
    clock: Callable[[], float] = time.monotonic
    logger: logging.Logger = field(default_factory=lambda: logging.getLogger("service_kit.inbox"))

    def __post_init__(self) -> None:
        self._queue: queue.Queue[Item] = queue.Queue(maxsize=self.capacity)
        self._counters: dict[str, InboxCounters] = {}
        self._lock = threading.Lock()
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
            self.log.warning(f"{kind}:refused", "%s: refused a %s (not from the paired board, or for no batch sent)", self.name, kind)
            return False
        if message is None:
            with self._lock:
                counters.handled += 1
            return True
        return self._put(counters, kind, message, arrival)

    def put(self, kind: str, message: Any, arrival: float | None = None) -> bool:
        """Queue an already decoded message (e.g. a liveliness change)."""
        return self._put(self._count(kind), kind, message, self.clock() if arrival is None else arrival)

    def _put(self, counters: InboxCounters, kind: str, message: Any, arrival: float) -> bool:
        try:
            self._queue.put_nowait(Item(kind, message, arrival))
        except queue.Full:
            with self._lock:
                counters.dropped_full += 1
            self.log.warning(f"{kind}:full", "%s: inbox full (%d items): dropped a %s", self.name, self.capacity, kind)
            return False
        with self._lock:
            counters.queued += 1
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
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def get_nowait(self) -> Item | None:
        try:
            return self._queue.get_nowait()
        except queue.Empty:
            return None

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
        return self._queue.qsize()

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
                for what in ("oversize", "undecodable", "refused", "dropped_full"):
                    n = getattr(c, what)
                    total += n
                    if n:
                        out[f"in_{kind}_{what}"] = n
        out["in_dropped"] = total
        return out
