"""What every service process shares at its edge: command-line parsing of
settings, logging, clean shutdown on SIGINT/SIGTERM, latency statistics
and the periodic health message."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from importlib.metadata import entry_points
from typing import Any, TypeVar

import numpy as np
import zenoh

from protocol.errors import ConfigError
from protocol.messages import Health, LatencyStats, encode
from protocol.setting_hints import ANY, unknown_setting
from protocol.settings import CommonSettings, describe, load_settings, retired
from service_kit import crash_report, readiness
from service_kit.encodings import JSON
from service_kit.interrupt import INTERRUPTED

S = TypeVar("S", bound=CommonSettings)
SERVICE_OF_MODEL = {"PlantSettings": "plant", "ControllerSettings": "controller", "DspSettings": "dsp", "CommonSettings": "common"}
"""The service whose settings a model holds (for the names a misspelt one is compared with)."""
T = TypeVar("T")


def parse_service_args(prog: str, summary: str, model: type[S], argv: Sequence[str] | None = None) -> S:
    """Parse ``--set NAME=VALUE`` overrides on top of ``RALF_*`` variables.

    ``--help`` lists every setting with its variable, default and meaning.
    A bad value exits with status 2 and a message naming the variable.
    """
    table = "\n".join(f"  {var:<34} {default:<16} {text}" for var, default, text in describe(model))
    parser = argparse.ArgumentParser(
        prog=prog,
        description=summary,
        epilog="settings (environment variable, default, meaning):\n" + table,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a setting, e.g. --set clock=lockstep")
    parser.add_argument(
        "--record",
        default=None,
        metavar="RUN.mcap",
        help="record the rig as this service sees it into an MCAP file (a `ralf-hil record` child process; see docs/recording.md)",
    )
    args = parser.parse_args(argv)
    overrides: dict[str, Any] = {}
    for item in args.set:
        name, sep, value = item.partition("=")
        name = name.strip().lower().removeprefix("ralf_")
        if sep and name not in model.model_fields and retired(name):
            parser.exit(2, f"{prog}: invalid configuration:\n  --set {name}: {retired(name)}\n")
        if not sep:
            parser.error(f"--set {item!r}: expected NAME=VALUE (the settings: {prog} --help)")
        if name not in model.model_fields:
            parser.exit(2, f"{prog}: --set {item!r}: {unknown_setting(name, SERVICE_OF_MODEL.get(model.__name__, ANY))}\n")
        overrides[name] = value
    try:
        settings = load_settings(model, overrides)
    except ConfigError as exc:
        parser.exit(2, f"{prog}: {exc}\n")
    return settings


def configure_logging(level: str, service: str) -> None:
    logging.basicConfig(
        level=getattr(logging, level),
        format=f"%(asctime)s {service} %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )


M_MMAP_THRESHOLD = -3
"""mallopt(3) parameter: allocations of at least this many bytes are mmapped (and unmapped at free)."""
MMAP_THRESHOLD_BYTES = 64 * 1024
"""Half glibc's initial 128 KiB, fixed (see :func:`fix_malloc_threshold`): at
128 KiB the controller's heap still grew ~0.5 MB/min (blocks between the two sizes
come from the heap then); at 64 KiB it stayed flat."""


def fix_malloc_threshold(threshold: int = MMAP_THRESHOLD_BYTES) -> bool:
    """Hold glibc's mmap threshold at ``threshold`` for the process's life.

    glibc raises its threshold to the size of any mmapped block that is freed
    (up to 32 MiB), after which mid-size blocks (numpy temporaries, zenoh's
    buffers) come from the heap, where frees between long-lived blocks leave
    holes: a real-time controller's heap grew ~0.6 MB/min with the bytes in
    use flat (mallinfo2: arena +1.3 MB in 3 min, in-use unchanged); with the
    threshold fixed at 64 KiB both stayed flat. Setting it also stops the
    dynamic adjustment. Returns False where there is no glibc ``mallopt``."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes

    try:
        return bool(ctypes.CDLL(None).mallopt(M_MMAP_THRESHOLD, int(threshold)))
    except (OSError, AttributeError):
        return False


PR_SET_PDEATHSIG = 1
"""prctl(2) option: the signal this process gets when its parent thread ends."""
LAUNCHER_POLL_S = 0.5


def follow_launcher(launcher_pid: int, stop: threading.Event, poll_s: float = LAUNCHER_POLL_S) -> threading.Thread | None:
    """End with the launcher: when ``launcher_pid`` (this process's parent) ends,
    by any signal, SIGKILL included, ``stop`` is set as a SIGTERM would set it.

    Linux's parent-death signal (``prctl(PR_SET_PDEATHSIG, SIGTERM)``) delivers
    SIGTERM the moment the parent ends; a thread also checks every ``poll_s``
    that the parent is still ``launcher_pid`` (a re-parented process has
    another), which covers a launcher that ended before the prctl and systems
    without it. Returns the watching thread (None when ``launcher_pid`` is 0)."""
    if not launcher_pid:
        return None
    log = logging.getLogger("runtime")
    if sys.platform.startswith("linux"):
        import ctypes

        try:
            libc = ctypes.CDLL(None, use_errno=True)
            if libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0) != 0:
                log.warning("parent-death signal refused (errno %d); watching the launcher only", ctypes.get_errno())
        except (OSError, AttributeError) as exc:
            log.warning("parent-death signal unavailable (%s); watching the launcher only", exc)

    def watch() -> None:
        while not stop.is_set():
            if os.getppid() != launcher_pid:
                log.warning("the launcher (pid %d) is gone; stopping", launcher_pid)
                stop.set()
                return
            stop.wait(poll_s)

    thread = threading.Thread(target=watch, name="launcher-watch", daemon=True)
    thread.start()
    return thread


def stop_on_signals(signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM), say: bool = True) -> tuple[threading.Event, list[str]]:
    """An event set when one of ``signals`` arrives, and the names of those
    received, in order.

    The handler only writes the signal's number to a pipe; a thread reads
    it, logs it and sets the event. Setting a :class:`threading.Event` in
    the handler itself takes the event's lock, which the interrupted main
    thread may hold (inside ``stop.wait()``, or in a handler interrupted by
    the next signal): the process then deadlocks and outlives its launcher
    (seen: a controller given four SIGTERMs within 0.1 s hung for good)."""
    stop = threading.Event()
    received: list[str] = []
    read_fd, write_fd = os.pipe()
    os.set_blocking(write_fd, False)

    def deliver() -> None:
        while True:
            data = os.read(read_fd, 64)
            if not data:
                return
            for signum in data:
                name = signal.Signals(signum).name
                received.append(name)
                if say:
                    logging.getLogger("runtime").info("received %s, stopping", name)
            stop.set()

    threading.Thread(target=deliver, name="stop-signals", daemon=True).start()

    def handler(signum: int, _frame: Any) -> None:
        try:
            os.write(write_fd, bytes([signum]))
        except OSError:  # the pipe is full of earlier signals: the event is being set already
            pass

    for signum in signals:
        signal.signal(signum, handler)
    return stop, received


def install_stop_handlers() -> threading.Event:
    """An event set by SIGINT or SIGTERM, so loops end and resources close (:func:`stop_on_signals`)."""
    return stop_on_signals()[0]


HEALTH_PERCENTILES = (50.0, 99.0, 99.9)


def sorted_percentiles(data: np.ndarray, qs: Sequence[float] = HEALTH_PERCENTILES) -> tuple[float, ...]:
    """``np.percentile(data, qs)`` (its default linear method, bit for bit),
    from one in-place ``data.sort()`` and a few float operations per
    percentile. ``data`` (float64, no NaN, not empty) is left sorted.

    Why not ``np.percentile``: it partitions the array in one C call that
    holds the GIL, 1.7 ms for the 65536 samples of a full tracker; twelve
    trackers in one health message kept a SCHED_FIFO loop from the GIL for
    ~20 ms twice a second (a C call cannot be pre-empted by the switch
    interval). numpy's sort takes 0.26 ms for the same array."""
    data.sort()
    n = data.size
    top = data[n - 1]
    out = []
    for q in qs:
        v = (n - 1) * (q / 100.0)  # the linear method's virtual index
        if v >= n - 1:
            out.append(float(top))
            continue
        if v < 0:
            out.append(float(data[0]))
            continue
        i = int(v // 1)
        a, b = float(data[i]), float(data[i + 1])
        t = v - i
        d = b - a
        out.append(b - d * (1 - t) if t >= 0.5 else a + d * t)  # numpy's _lerp
    return tuple(out)


class LatencyTracker:
    """Keeps the most recent ``capacity`` samples of one latency (seconds)
    and summarises them as p50/p99/p99.9/max; the maximum and count cover
    the whole run."""

    def __init__(self, capacity: int = 65536) -> None:
        # Written through at once (np.full stores every element): np.zeros takes
        # zeroed pages from the kernel that become resident only as the ring first
        # fills, so each 200 Hz tracker grew the process by 1.6 KB/s for its first
        # 5.5 minutes, a slope that read like a leak in long runs (docs/reliability.md).
        self._buf = np.full(capacity, 0.0)
        self._size = self._buf.size
        self._store: Any = memoryview(self._buf.data)  # float64 items (typeshed types a memoryview as bytes)
        """``_buf``'s memory: storing a float through it costs a fifth of numpy's item assignment."""
        self._n = 0
        self._max = 0.0
        self._lock = threading.Lock()
        self._stats: LatencyStats | None = None

    def add(self, seconds: float) -> None:
        """One sample, from the tracker's one writer (the thread that measures
        it: the loop's, for the controller's TET). No lock on this per-tick
        path (the lock cost 5x the store): the sample is stored, then the
        maximum, then the count, so a reader (:meth:`values`, :meth:`stats`,
        which copy under the lock) never counts a sample not yet stored."""
        n = self._n
        self._store[n % self._size] = seconds
        if seconds > self._max:
            self._max = seconds
        self._n = n + 1

    @property
    def count(self) -> int:
        return self._n

    @property
    def last(self) -> float:
        """The most recent sample (0.0 before the first)."""
        n = self._n
        return float(self._store[(n - 1) % self._size]) if n else 0.0

    def values(self) -> np.ndarray:
        with self._lock:
            return self._buf[: min(self._n, self._buf.size)].copy()

    def stats(self) -> LatencyStats:
        """p50/p99/p99.9 of the kept samples (:func:`sorted_percentiles`), the
        run's count and maximum; the same samples give the same answer without
        recomputing it (health asks every period, often with nothing new)."""
        with self._lock:
            n, top = self._n, self._max
            cached = self._stats
            if cached is not None and cached.count == n:
                return cached
            data = self._buf[: min(n, self._buf.size)].copy()
        if data.size == 0:
            return LatencyStats(count=0, p50=0.0, p99=0.0, p999=0.0, max=0.0)
        p50, p99, p999 = sorted_percentiles(data)
        stats = self._stats = LatencyStats(count=n, p50=p50, p99=p99, p999=p999, max=top)
        return stats


class HealthPublisher:
    """Publishes ``build()`` on ``key`` every ``period_s`` from a daemon thread."""

    def __init__(self, session: zenoh.Session, key: str, period_s: float, build: Callable[[int], Health]) -> None:
        self._pub = session.declare_publisher(key, encoding=JSON)
        self._period = period_s
        self._build = build
        self._seq = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="health", daemon=True)
        self._priority = 0

    def start(self) -> HealthPublisher:
        from service_kit.realtime import helper_priority

        self._priority = helper_priority()  # started by a FIFO loop: one level below it
        self._thread.start()
        return self

    def publish_now(self) -> None:
        self._pub.put(encode(self._build(self._seq)))
        self._seq += 1

    def _run(self) -> None:
        from service_kit.realtime import lower_current_thread

        lower_current_thread(self._priority)  # started by a FIFO loop: one level below it
        while not self._stop.wait(self._period):
            try:
                self.publish_now()
            except Exception:  # a closing session must not kill the thread noisily
                logging.getLogger("runtime").debug("health publish failed", exc_info=True)

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        try:
            self.publish_now()
        except Exception:
            logging.getLogger("runtime").debug("final health publish failed", exc_info=True)
        self._pub.undeclare()


def build_or_config_error(what: str, factory: Callable[[], T]) -> T:
    """Build a service's core from its settings; a value the core refuses
    (a design the OATF rejects, an identifier setting out of range, a
    missing trajectory file) becomes a :class:`ConfigError` naming it."""
    try:
        return factory()
    except ConfigError:
        raise
    except (ValueError, OSError) as exc:
        raise ConfigError(f"{what}: {exc}") from None


RECORDER_HOOK = "ralf_hil.service_recorder"
"""Entry-point group of ``--record``'s hook: the launcher's package registers
one (``workbench.recording.attach:attach_recorder``); a service image without
the launcher has none that loads, and ``--record`` is refused in one line."""

RecorderHook = Callable[[CommonSettings, str], Callable[[], None]]
"""Starts recording the service's rig into the file beside the service
(settings, path) and returns the function that stops it."""


def installed_recorder_hook() -> RecorderHook:
    """The ``--record`` hook the installed launcher registers under
    :data:`RECORDER_HOOK`; :class:`ImportError` when none loads."""
    for entry in entry_points(group=RECORDER_HOOK):
        hook: RecorderHook = entry.load()
        return hook
    raise ImportError(f"no {RECORDER_HOOK!r} entry point is installed")


def split_record_arg(args: Sequence[str]) -> tuple[str | None, list[str]]:
    """``(path, args without --record PATH / --record=PATH)``."""
    path: str | None = None
    out: list[str] = []
    i = 0
    while i < len(args):
        a = args[i]
        if a == "--record" and i + 1 < len(args):
            path = args[i + 1]
            i += 2
            continue
        if a.startswith("--record="):
            path = a.split("=", 1)[1]
        else:
            out.append(a)
        i += 1
    return path, out


def _not_recording() -> None:
    """Stopping the recorder when none was started."""


def run_service(
    prog: str,
    summary: str,
    model: type[S],
    body: Callable[[S, zenoh.Session, threading.Event], int],
    argv: Sequence[str] | None = None,
    recorder: RecorderHook | None = None,
) -> int:
    """The life of a service process: settings, logging, SIGINT/SIGTERM, a
    zenoh session closed on every path, and ``body``'s exit code.

    ``--record RUN.mcap`` starts ``recorder`` beside the service once its
    session is open (default: the hook the installed launcher registers,
    :func:`installed_recorder_hook`) and stops it on every way out."""
    # Imported here so that parsing --help does not need a network stack.
    from service_kit.transport import open_zenoh
    from service_kit.zenoh_log import route_to_logging

    args = list(sys.argv[1:] if argv is None else argv)
    record: str | None = None
    stop_recording: Callable[[], None] = _not_recording
    if any(a == "--record" or a.startswith("--record=") for a in args):
        # The recorder is the launcher's, reached through its hook: a board never imports the launcher.
        if recorder is None:
            try:
                recorder = installed_recorder_hook()
            except ImportError as exc:  # a service image carries no launcher
                print(f"{prog}: --record needs the launcher's recorder (pip install 'ralf-hil[rig]'): {exc}", file=sys.stderr)
                return 2
        record, args = split_record_arg(args)
    settings = parse_service_args(prog, summary, model, args)
    fix_malloc_threshold()
    configure_logging(settings.log_level, prog.removeprefix("ralf-"))
    crash_report.enable()  # a crash in native code (an FMU's doStep) leaves its Python frames in the log
    route_to_logging()  # zenoh's own log lines as this service's log records
    readiness.watch_compiles()  # before any kernel is touched: the ready line counts what compiled
    readiness.clear(settings.ready_file)  # a previous run's, in a restarted container
    stop, received = stop_on_signals()
    finished = threading.Event()
    end_a_start_that_cannot_stop(stop, finished, received)
    follow_launcher(settings.launcher_pid, stop)
    try:
        try:
            session = open_zenoh(settings, stop=stop)
        except ConfigError as exc:  # a TransportError: one line, exit 2
            if stop.is_set():  # asked to stop while waiting for the router: a clean stop
                logging.getLogger(prog).info("%s", exc)
                return exit_code(0, received)
            logging.getLogger(prog).error("%s", exc)
            return 2
        if record and recorder is not None:
            stop_recording = recorder(settings, record)
        try:
            return exit_code(body(settings, session, stop), received)
        except ConfigError as exc:
            logging.getLogger(prog).error("%s", exc)
            return 2
        finally:
            readiness.clear(settings.ready_file)
            session.close()
            stop_recording()
    finally:
        finished.set()


def exit_code(code: int, received: Sequence[str]) -> int:
    """A service's exit code: :data:`~service_kit.interrupt.INTERRUPTED` (130)
    when Ctrl-C (SIGINT) stopped a run that ended cleanly, as a shell expects
    of an interrupted command; SIGTERM (a launcher's or a container engine's
    stop) is an ordinary end, 0; a fault keeps its own code."""
    return INTERRUPTED if code == 0 and "SIGINT" in received else code


START_STOP_GRACE_S = 1.0
"""How long a service that is not ready yet is given to stop in order after
SIGINT/SIGTERM before it ends at once (:func:`end_a_start_that_cannot_stop`)."""


def end_a_start_that_cannot_stop(
    stop: threading.Event,
    finished: threading.Event,
    received: Sequence[str],
    grace_s: float = START_STOP_GRACE_S,
    end: Callable[[int], None] = os._exit,
) -> threading.Thread:
    """Ctrl-C within a couple of seconds, even in a first start-up.

    A service stops in order at ``stop`` from every wait of its start-up
    (the router, the plant, the DSP), but not from inside numba compiling a
    kernel (tens of seconds at a first run, in one C call). When ``stop`` is
    set and the service is still not ready (:data:`service_kit.readiness.READY`)
    and not ``finished`` ``grace_s`` later, it has nothing to save yet: this
    thread logs one line and ends the process (``end``) with the code an
    orderly stop would give. A ready service is never ended this way (its
    run record and recording close in order)."""
    log = logging.getLogger("runtime")

    def watch() -> None:
        while not stop.wait(0.5):
            if finished.is_set():
                return
        if finished.wait(grace_s) or readiness.READY.is_set():
            return
        log.info("still starting %.1f s after %s (a kernel compiling); ending now", grace_s, received[0] if received else "the stop")
        logging.shutdown()
        end(exit_code(0, received))

    thread = threading.Thread(target=watch, name="start-stop-guard", daemon=True)
    thread.start()
    return thread
