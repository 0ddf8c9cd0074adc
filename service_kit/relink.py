"""A node that cannot link again opens a new session with a new zenoh id.

zenoh adds a link from an already linked zenoh id to that id's session
only when the two ends authenticated alike (service_kit/access.py), and a
session's id is fixed for its life. So while a node is cut off (stopped,
its links' lease expired), any session that may join the rig (a tool's,
with ``tool.env``) can claim the node's id, which it can read off the
rig (the DSP's board id, zenoh's own peer lists); when the node comes
back, every other node refuses its links, since that id is linked already
under another user name, for as long as the claimer holds it.

:class:`RelinkWatch` watches a session's links: once it has had a peer or
router, :data:`ALONE_S` seconds with none make it call ``replace``, which
takes the service's publishers, subscribers and tokens off the old session,
closes it (freeing its listening port), opens a new one from the same
configuration (zenoh gives it a new random id) and declares them there
again; the node links again under its new id and
says so in one line naming the id it gave up. A node that stays alone (the
rig has ended) tries again after twice as long each time, up to
:data:`MAX_BACKOFF_S`.

All three nodes use it the same way (:func:`relinking`): what a node
declares on its session is held by parts that can :meth:`Rebinds.unbind`
from one session and :meth:`Rebinds.bind` to another, each with an
``out_lock`` held while it sends; :func:`move_to_new_session` holds every
part's lock for the move, so nothing goes out on a closed session. A part
on a real-time path (the controller's batches, the plant's truth) does not
wait for its lock: what it would send while the node moves is dropped and
counted, since a node left alone reaches nobody anyway.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from functools import partial
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from protocol.settings import CommonSettings

log = logging.getLogger(__name__)

ALONE_S = 1.0
"""Seconds without any link, after having had one, before the node takes a new id."""
POLL_S = 0.1
"""How often the links are looked at."""
MAX_BACKOFF_S = 30.0
"""The longest wait between two new sessions of a node that stays alone."""


def linked(session: Any) -> int:
    """The peers and routers ``session`` has a link to (none for a session
    that cannot say: closed by a move whose new session failed to open)."""
    try:
        return len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))
    except Exception:  # noqa: BLE001 (zenoh raises its own error on a closed session)
        return 0


class RelinkWatch:
    """Has ``replace(old)`` put a node left alone on a new session and return
    it (module docstring).
    :attr:`session` is the one in use; :attr:`relinks` counts new sessions.
    ``clock`` and ``count_links`` are injectable for tests."""

    def __init__(
        self,
        session: Any,
        replace: Callable[[Any], Any],
        clock: Callable[[], float] = time.monotonic,
        count_links: Callable[[Any], int] = linked,
    ) -> None:
        self.session = session
        self._replace = replace
        self._clock = clock
        self._count = count_links
        self.relinks = 0
        self._had_link = False
        self._alone_since: float | None = None
        self._wait_s = ALONE_S
        self._thread: threading.Thread | None = None

    def check(self) -> bool:
        """Look at the links once; True if a new session was taken."""
        now = self._clock()
        if self._count(self.session):
            self._had_link, self._alone_since, self._wait_s = True, None, ALONE_S
            return False
        if not self._had_link:
            return False
        if self._alone_since is None:
            self._alone_since = now
            return False
        if now - self._alone_since < self._wait_s:
            return False
        alone_for = now - self._alone_since
        old = self.session
        gave_up = str(old.info.zid())
        new = self._replace(old)
        self.session = new
        self.relinks += 1
        self._alone_since = now
        self._wait_s = min(MAX_BACKOFF_S, self._wait_s * 2)
        log.warning(
            "no link to any node of the rig for %.1f s: zenoh id %s given up (a session that is not this node may hold it); linking again as %s",
            alone_for,
            gave_up,
            new.info.zid(),
        )
        return True

    def start(self, stop: threading.Event) -> RelinkWatch:
        """Check every :data:`POLL_S` seconds in a thread of its own until ``stop``."""

        def loop() -> None:
            while not stop.wait(POLL_S):
                try:
                    self.check()
                except Exception:  # a failed new session: the old one stays, tried again later
                    log.exception("could not open a new zenoh session")
                    self._alone_since = self._clock()

        self._thread = threading.Thread(target=loop, name="relink-watch", daemon=True)
        self._thread.start()
        return self

    def join(self, timeout: float = 5.0) -> None:
        if self._thread is not None:
            self._thread.join(timeout)


class MovingOut:
    """The out lock of a part on a real-time path, and its counts: :meth:`send`
    puts through it without waiting; while the part moves (or after a move
    that failed half-way) what is sent is dropped and counted."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.bound = False
        self.binds = 0
        self.dropped = 0

    def bound_to_new(self) -> None:
        """The part is on a session (its first, or a new one after a move)."""
        self.bound = True
        self.binds += 1

    def send(self, put: Callable[[], None]) -> None:
        if not self.lock.acquire(blocking=False):
            self.dropped += 1
            return
        try:
            if self.bound:
                put()
            else:
                self.dropped += 1
        finally:
            self.lock.release()

    def as_dict(self) -> dict[str, int]:
        """``zenoh_relinks`` (moves to a new session) and ``zenoh_dropped_moving``, for health."""
        return {"zenoh_relinks": max(0, self.binds - 1), "zenoh_dropped_moving": self.dropped}


class MovablePort:
    """A port whose parts move to a new session: its :class:`MovingOut` (set
    by the port's ``__init__``), its out lock and what it dropped meanwhile."""

    moves: MovingOut

    @property
    def out_lock(self) -> threading.Lock:
        """Held while a message goes out, and while the port moves to a new session."""
        return self.moves.lock

    @property
    def dropped_moving(self) -> int:
        return self.moves.dropped


class Rebinds(Protocol):
    """What a node declares on its zenoh session, movable to another one."""

    @property
    def out_lock(self) -> threading.Lock:
        """Held while a message goes out, and while the part moves."""
        ...

    def unbind(self) -> None:
        """Everything declared on the session undeclared (the session may be broken: nothing raises)."""
        ...

    def bind(self, session: Any) -> None:
        """Everything declared again on ``session``."""
        ...


def move_to_new_session(open_session: Callable[[], Any], parts: Sequence[Rebinds], old: Any) -> Any:
    """``parts`` off ``old``, ``old`` closed (its listening port freed), ``parts``
    on ``open_session()`` (a new zenoh id), every part's ``out_lock`` held
    meanwhile. Called only while no node links to this one, so no message is
    on its way in. If the new session cannot be opened, the parts stay
    unbound and the error propagates (:meth:`RelinkWatch.start` tries again)."""
    with ExitStack() as held:
        for part in parts:
            held.enter_context(part.out_lock)
        for part in parts:
            part.unbind()
        old.close()
        new = open_session()
        for part in parts:
            part.bind(new)
    return new


class Relinking:
    """A node's :class:`RelinkWatch` for :func:`relinking`: :attr:`session` is the one in use."""

    def __init__(self, watch: RelinkWatch, stop: threading.Event) -> None:
        self.watch = watch
        self._stop = stop

    @property
    def session(self) -> Any:
        return self.watch.session

    @property
    def relinks(self) -> int:
        return self.watch.relinks

    def halt(self) -> None:
        """No further move (call it before closing the parts); idempotent."""
        self._stop.set()
        self.watch.join()


@contextmanager
def relinking(settings: CommonSettings, session: Any, parts: Sequence[Rebinds]) -> Iterator[Relinking]:
    """Watch ``session``'s links while the block runs and move ``parts`` to a
    new session of ``settings``'s configuration when the node is left alone
    (module docstring). On the way out the watch is halted and a session it
    opened is closed (the caller closes ``session``, the one it opened):
    halt it yourself before closing the parts."""
    from service_kit.transport import open_zenoh

    stop = threading.Event()
    watch = RelinkWatch(session, partial(move_to_new_session, partial(open_zenoh, settings, retry_for_s=0.0), parts)).start(stop)
    held = Relinking(watch, stop)
    try:
        yield held
    finally:
        held.halt()
        if watch.session is not session:
            watch.session.close()
