"""When a service is ready, and what its start cost.

Every service logs one line when it is ready to do its work::

    ready in 1.84 s (process start to ready); numba kernels: 5 loaded from cache, 0 compiled

and, when ``ready_file`` is set (``RALF_READY_FILE``), writes that file
(its process id, the seconds it took) and removes it when it exits. A
container healthcheck asks ``python -m service_kit.readiness FILE``: exit 0
when the file names a live process, 1 with one line otherwise (cheap: it
imports nothing of the rig).

The kernels' figures come from numba itself: ``compiled`` counts its
``numba:compile`` events (a cache load raises none), ``loaded from cache``
sums the cache hits of the rig's compiled functions. A service image warmed
at build time shows ``0 compiled``; a kernel compiled at start costs
seconds and is named in the line, which is what the compose run in CI
checks (``.ci/compose-rig``).
"""

from __future__ import annotations

import json
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

log = logging.getLogger("readiness")

PACKAGES = ("protocol", "service_kit", "plant_emulator", "controller", "dsp_service")
"""Where the rig's compiled functions live."""

READY_LINE = re.compile(
    r"ready in (?P<seconds>[0-9.]+) s \(process start to ready\); numba kernels: (?P<cached>\d+) loaded from cache, (?P<compiled>\d+) compiled"
)


@dataclass(frozen=True)
class Readiness:
    """One service's start: seconds from process start to ready, kernels loaded and compiled."""

    seconds: float
    cached: int
    compiled: int
    compiled_names: tuple[str, ...] = ()

    def line(self) -> str:
        names = f" ({', '.join(self.compiled_names)})" if self.compiled_names else ""
        return f"ready in {self.seconds:.2f} s (process start to ready); numba kernels: {self.cached} loaded from cache, {self.compiled} compiled{names}"


def parse_ready_line(text: str) -> Readiness | None:
    """The first ready line in a log (``None`` if there is none)."""
    m = READY_LINE.search(text)
    if m is None:
        return None
    return Readiness(seconds=float(m["seconds"]), cached=int(m["cached"]), compiled=int(m["compiled"]))


class CompileCounter:
    """Counts numba compilations in this process (its ``numba:compile`` event), by function name."""

    def __init__(self) -> None:
        self.names: list[str] = []
        self._lock = threading.Lock()
        self.installed = False

    def install(self) -> CompileCounter:
        try:
            from numba.core import event
        except ImportError:  # without numba the kernels run as Python: nothing compiles
            return self
        counter = self

        class _Listener(event.Listener):
            def on_start(self, ev: Any) -> None:
                dispatcher = (ev.data or {}).get("dispatcher")
                name = getattr(getattr(dispatcher, "py_func", None), "__qualname__", None) or str(dispatcher)
                module = getattr(getattr(dispatcher, "py_func", None), "__module__", "")
                with counter._lock:
                    first = not counter.names
                    counter.names.append(f"{module}.{name}" if module else name)
                if first:  # a first run, or a cache made stale: say why start-up is slow
                    log.info("compiling the numba kernels (%s first), once: ~30-60 s; later runs load them from the on-disk cache", name)

            def on_end(self, ev: Any) -> None:
                pass

        event.register("numba:compile", _Listener())
        self.installed = True
        return self

    def compiled(self) -> tuple[str, ...]:
        with self._lock:
            return tuple(self.names)


COMPILES = CompileCounter()
"""This process's counter, installed by :func:`watch_compiles` before the first kernel is touched."""


def watch_compiles() -> None:
    """Start counting numba compilations (once per process)."""
    if not COMPILES.installed:
        COMPILES.install()


def cache_hits(modules: Iterable[Any] | None = None) -> int:
    """Cache loads of the compiled functions found in the rig's loaded modules."""
    try:
        from numba.core.dispatcher import Dispatcher
    except ImportError:
        return 0
    if modules is None:
        modules = [m for name, m in sys.modules.copy().items() if name.split(".")[0] in PACKAGES and m is not None]  # another thread may import meanwhile
    seen: set[int] = set()
    hits = 0
    for module in modules:
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher) and id(value) not in seen:
                seen.add(id(value))
                hits += sum(value.stats.cache_hits.values())
    return hits


def process_age_s(now: Callable[[], float] = time.time, proc: Path = Path("/proc")) -> float:
    """Seconds since this process started (Linux: from /proc; elsewhere since this module was imported)."""
    try:
        fields = (proc / "self" / "stat").read_text().rsplit(")", 1)[1].split()
        start_ticks = int(fields[19])  # field 22, starttime, in clock ticks since boot
        boot = next(int(line.split()[1]) for line in (proc / "stat").read_text().splitlines() if line.startswith("btime "))
        return max(0.0, now() - (boot + start_ticks / os.sysconf("SC_CLK_TCK")))
    except (OSError, ValueError, IndexError, StopIteration):
        return max(0.0, now() - _IMPORTED)


_IMPORTED = time.time()


READY = threading.Event()
"""Set once this process is ready (:func:`mark_ready`): a stop before it may end the process at once."""


def mark_ready(ready_file: str = "", logger: logging.Logger | None = None, age_s: float | None = None) -> Readiness:
    """Log the ready line and write ``ready_file`` (when set)."""
    READY.set()
    compiled = COMPILES.compiled()
    ready = Readiness(
        seconds=process_age_s() if age_s is None else age_s, cached=cache_hits(), compiled=len(compiled), compiled_names=tuple(sorted(set(compiled)))
    )
    (logger or log).info("%s", ready.line())
    if ready_file:
        path = Path(ready_file)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps({"pid": os.getpid(), "seconds": round(ready.seconds, 3), "compiled": ready.compiled}) + "\n")
        tmp.replace(path)
    return ready


def clear(ready_file: str) -> None:
    """Remove the ready file (at start, a previous run's; at exit, this one's)."""
    if ready_file:
        Path(ready_file).unlink(missing_ok=True)


def check(path: Path, alive: Callable[[int], bool] | None = None) -> tuple[bool, str]:
    """Whether ``path`` says a live process is ready, and why not."""
    try:
        pid = int(json.loads(path.read_text())["pid"])
    except FileNotFoundError:
        return False, f"not ready: {path} does not exist (the service is starting, or has stopped)"
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return False, f"not ready: {path} is unreadable: {exc}"
    if not (alive or _alive)(pid):
        return False, f"not ready: {path} names process {pid}, which is gone"
    return True, f"ready: process {pid}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or args[0].startswith("-"):
        print("usage: python -m service_kit.readiness READY_FILE   (exit 0 when the service that writes it is ready)", file=sys.stderr)
        return 2
    ok, why = check(Path(args[0]))
    print(why, file=sys.stdout if ok else sys.stderr)
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
