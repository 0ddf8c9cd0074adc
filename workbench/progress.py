"""Progress a log can follow: what a long command prints when its output is
not a terminal (a CI job, ``| tee``, a file).

On a terminal the commands draw their own live lines (``up``'s status line,
the experiments' bars); those are invisible in a log. Without a terminal,
:class:`Heartbeat` watches everything written to stdout and stderr and, when
nothing was written for :data:`PROGRESS_INTERVAL_S`, writes one line saying
what the command is doing (the current :func:`activity`: simulated time,
ticks, misses when a rig is running), so no log stays silent longer than
that. :class:`ServiceLogWatch` turns the services' own log lines into
start-up progress (kernels compiling, each service ready).

Every decision takes its time from an injected clock (:class:`Heartbeat`'s
``clock``), so the interval logic is tested without waiting.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from service_kit.readiness import READY_LINE

if TYPE_CHECKING:  # this module loads before the rig's modules (workbench/__main__.py): the standard library only
    from protocol.messages import ControllerStatus

PROGRESS_INTERVAL_S = 5.0
"""Without a terminal, the longest a long command stays silent."""

LONG_COMMANDS = frozenset({"up", "experiment", "timing-test", "sweep", "bench", "memory-slope", "measure", "plant", "replay", "search"})
"""``ralf-hil`` commands that can run for minutes: without a terminal they say how they progress."""

_activity: list[Callable[[], str]] = []
"""What the command is doing now, innermost last (:func:`activity`)."""
_activity_lock = threading.Lock()


@contextmanager
def activity(describe: Callable[[], str] | str) -> Iterator[None]:
    """While the block runs, the heartbeat's line says ``describe()`` (called
    from the heartbeat's thread: it should only read)."""
    fn = describe if callable(describe) else (lambda: describe)
    with _activity_lock:
        _activity.append(fn)
    try:
        yield
    finally:
        with _activity_lock:
            _activity.remove(fn)


def current_activity() -> str:
    """The innermost :func:`activity`'s description ('' when none, or when it failed)."""
    with _activity_lock:
        fn = _activity[-1] if _activity else None
    if fn is None:
        return ""
    try:
        return fn()
    except Exception:  # a description read mid-update: the next beat tries again
        return ""


def status_progress(status: ControllerStatus | None, waiting: str = "waiting for the controller's first tick") -> str:
    """A rig's progress in one plain line: simulated time, ticks, misses."""
    if status is None:
        return waiting
    return (
        f"sim {status.sim_time_s:.2f} s, ticks {status.ticks}, deadline misses {status.deadline_misses}, "
        f"overruns {status.overruns}, batches {status.batches_sent}, interrupts {status.interrupts}"
    )


def controller_progress(controller: Any) -> str:
    """An in-process controller's progress (a co-simulation's): its last
    published status, or its tick count before the first one."""
    from protocol.messages import ControllerStatus, decode

    payload = getattr(getattr(controller, "port", None), "status", None)
    if payload:
        return status_progress(decode(ControllerStatus, payload))
    return f"ticks {controller.tick}"


def compiling_progress() -> str:
    """This process's numba compilations so far (:mod:`service_kit.readiness`), '' when none."""
    from service_kit.readiness import COMPILES

    compiled = COMPILES.compiled()
    return f"compiling the numba kernels (first run, or a stale cache), once: ~30-60 s; {len(compiled)} compiled so far" if compiled else ""


PROGRESS_LINE = re.compile(r"^ralf-hil [\w-]+: \d+ s, ")
"""A heartbeat's line (``ralf-hil up: 5 s, loading the rig's modules``): progress, not a message."""


def messages(text: str) -> list[str]:
    """The non-empty lines of a command's stderr that are not progress lines: what it had to say."""
    return [line for line in text.splitlines() if line.strip() and not PROGRESS_LINE.match(line)]


class Heartbeat:
    """Writes a progress line whenever nothing was written for ``interval_s``.

    :meth:`saw_output` is called on every write to the watched streams
    (:class:`WatchedStream`); :meth:`check` decides, on ``clock``, whether a
    line is due and writes it. :meth:`start` runs :meth:`check` on a thread."""

    def __init__(
        self,
        write: Callable[[str], None],
        label: str,
        *,
        interval_s: float = PROGRESS_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._write = write
        self.label = label
        self.interval_s = interval_s
        self._clock = clock
        self.started = clock()
        self.last_output = self.started
        self.beats = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def saw_output(self) -> None:
        self.last_output = self._clock()

    def line(self, now: float) -> str:
        doing = current_activity()
        return f"{self.label}: {now - self.started:.0f} s" + (f", {doing}" if doing else ", running")

    def check(self) -> bool:
        """Write the progress line if ``interval_s`` passed since the last output; whether it did."""
        now = self._clock()
        if now - self.last_output < self.interval_s:
            return False
        self.beats += 1
        self._write(self.line(now) + "\n")
        self.last_output = now
        return True

    def start(self, poll_s: float = 0.25) -> Heartbeat:
        def run() -> None:
            while not self._stop.wait(poll_s):
                self.check()

        self._thread = threading.Thread(target=run, name="progress-heartbeat", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)


class WatchedStream:
    """A text stream that tells a :class:`Heartbeat` about every write and
    passes everything else (``isatty``, ``fileno``, ``encoding``) through."""

    def __init__(self, stream: IO[str], heartbeat: Heartbeat) -> None:
        self._stream = stream
        self.heartbeat = heartbeat

    def write(self, text: str) -> int:
        written = self._stream.write(text)
        if text:
            self._stream.flush()  # a log reader sees the line now, not at exit
            self.heartbeat.saw_output()
        return written

    def flush(self) -> None:
        self._stream.flush()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextmanager
def heartbeat_unless_terminal(label: str, *, interval_s: float = PROGRESS_INTERVAL_S) -> Iterator[Heartbeat | None]:
    """Around a long command: when stderr is not a terminal, watch stdout and
    stderr and write a progress line to stderr after every ``interval_s`` of
    silence. On a terminal nothing changes (yields None)."""
    if isinstance(sys.stderr, WatchedStream):  # one heartbeat per process: the outer one goes on
        yield sys.stderr.heartbeat
        return
    if sys.stderr.isatty():
        yield None
        return
    err, out = sys.stderr, sys.stdout

    def write(text: str) -> None:
        err.write(text)
        err.flush()

    beat = Heartbeat(write, label, interval_s=interval_s)
    sys.stderr, sys.stdout = WatchedStream(err, beat), WatchedStream(out, beat)
    beat.start()
    try:
        yield beat
    finally:
        beat.stop()
        if isinstance(sys.stderr, WatchedStream):
            sys.stderr = err
        if isinstance(sys.stdout, WatchedStream):
            sys.stdout = out


COMPILING = re.compile(r"compiling the numba kernels \((?P<first>[^)]*) first\)")


class ServiceLogWatch:
    """Start-up progress from the services' log files: the first line saying
    a service compiles its numba kernels, and its ``ready in`` line
    (:mod:`service_kit.readiness`), each once per service."""

    def __init__(self, logs: Mapping[str, Path]) -> None:
        self.logs = dict(logs)
        self._offset = dict.fromkeys(self.logs, 0)
        self._partial = dict.fromkeys(self.logs, "")
        self._said: set[tuple[str, str]] = set()

    def events(self) -> list[str]:
        """The start-up lines that appeared since the last call."""
        out = []
        for name, path in self.logs.items():
            try:
                with open(path, "rb") as fh:
                    fh.seek(self._offset[name])
                    chunk = fh.read()
            except OSError:
                continue
            self._offset[name] += len(chunk)
            *lines, self._partial[name] = (self._partial[name] + chunk.decode(errors="replace")).split("\n")
            for line in lines:
                event = self._event(name, line)
                if event is not None:
                    out.append(event)
        return out

    def _event(self, name: str, line: str) -> str | None:
        compiling, ready = COMPILING.search(line), READY_LINE.search(line)
        if compiling and (name, "compiling") not in self._said:
            self._said.add((name, "compiling"))
            return f"{name}: compiling the numba kernels (first run, or a stale cache), once: ~30-60 s"
        if ready and (name, "ready") not in self._said:
            self._said.add((name, "ready"))
            return f"{name}: {ready.group(0)}"
        return None
