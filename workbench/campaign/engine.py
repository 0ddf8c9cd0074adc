"""The campaign engine: independent tasks on Dask distributed.

An :class:`Engine` wraps a ``distributed.Client``: :meth:`Engine.local`
starts an embedded ``LocalCluster`` on 127.0.0.1 (one single-threaded worker
process per core by default, no dashboard), :meth:`Engine.connect` joins a
running scheduler (``tcp://HOST:8786``, started with ``dask scheduler`` and
fed by ``dask worker`` on any number of machines; see docs/campaigns.md).

:meth:`Engine.map` runs ``fn(item)`` for every item, each as its own task,
under a rich progress bar, and returns one :class:`TaskOutcome` per item in
the order of the items. An exception inside a task, or a worker dying under
it, becomes that outcome's ``error`` (with the traceback); the other tasks
run on. Every task reports where and how long it ran on the worker, so the
engine's overhead (scheduling, transfer) is what is left of the client's
round trip.

Experiments share one engine per process: :func:`current_engine` returns the
one installed with :func:`use_engine` (``ralf-hil experiment --scheduler``)
or starts a local one on first use (closed at exit).
"""

from __future__ import annotations

import atexit
import logging
import os
import signal
import socket
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from multiprocessing import resource_tracker
from typing import Any, Generic, TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from workbench.progress import activity
from workbench.service_warnings import add_remote, counted_warnings

__all__ = [
    "Engine",
    "EngineError",
    "TaskOutcome",
    "current_engine",
    "engine_scope",
    "use_engine",
]

T = TypeVar("T")
R = TypeVar("R")


class EngineError(RuntimeError):
    """The engine cannot start or reach its scheduler."""


@dataclass
class TaskOutcome(Generic[R]):
    """One task's result, or its error."""

    index: int
    """Position of the item in the list given to :meth:`Engine.map`."""
    key: str
    value: R | None = None
    error: str = ""
    """Empty on success; else the exception and its traceback (or the worker's death)."""
    worker: str = ""
    """``host:pid`` of the worker process that ran it."""
    run_s: float = float("nan")
    """Wall time of ``fn(item)`` on the worker."""
    round_trip_s: float = float("nan")
    """Client side: from submission until the result was in the client's hands."""

    @property
    def ok(self) -> bool:
        return not self.error


def _timed_call(fn: Callable[[Any], Any], item: Any) -> tuple[bool, Any, float, str, dict[str, Any]]:
    """Worker side: ``fn(item)``, its wall time, where it ran and the rig's
    warnings counted during it (:mod:`workbench.service_warnings`); an exception is returned as text."""
    where = f"{socket.gethostname()}:{os.getpid()}"
    started = time.perf_counter()
    with counted_warnings() as warned:
        try:
            value = fn(item)
        except Exception as exc:  # noqa: BLE001 - one run's failure is its row, not the campaign's
            text = f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}"
            return False, text, time.perf_counter() - started, where, warned.as_dict()
    return True, value, time.perf_counter() - started, where, warned.as_dict()


class Engine:
    """A Dask distributed client and, for a local engine, its cluster."""

    def __init__(self, client: Any, cluster: Any = None, *, started_s: float = float("nan")) -> None:
        self.client = client
        self.cluster = cluster
        self.started_s = started_s
        """Wall time from asking for the cluster until every worker had joined (local engines)."""
        self._closed = False

    # -- construction ----------------------------------------------------------------
    @classmethod
    def local(cls, workers: int | None = None, *, processes: bool = True, threads_per_worker: int = 1, memory_limit: str = "auto") -> Engine:
        """An embedded ``LocalCluster`` on 127.0.0.1: ``workers`` single-threaded worker
        processes (default: one per core), random ports, no dashboard."""
        from distributed import Client, LocalCluster

        n = workers or os.cpu_count() or 1
        started = time.perf_counter()
        # SIGINT blocked while the cluster starts: its event-loop thread, and through it
        # every worker process, inherit the block, so a terminal's Ctrl-C (sent to the
        # whole process group) reaches only this process, which ends the workers itself
        # (abort), instead of each worker printing a KeyboardInterrupt mid-import.
        # A Ctrl-C meanwhile is held and raised once the cluster stands. multiprocessing's
        # resource tracker is started first: starting it unblocks SIGINT in the calling thread.
        resource_tracker.ensure_running()
        unblocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=threads_per_worker,
                processes=processes,
                host="127.0.0.1",
                scheduler_port=0,
                dashboard_address=None,
                memory_limit=memory_limit,
                silence_logs=logging.CRITICAL,
            )
        except Exception as exc:
            raise EngineError(f"cannot start a local Dask cluster of {n} worker(s): {exc}") from exc
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, unblocked)
        engine = cls(None, cluster)
        try:
            engine.client = Client(cluster)
            engine.client.wait_for_workers(n, timeout=120)
        except Exception as exc:
            engine.abort()
            raise EngineError(f"cannot start a local Dask cluster of {n} worker(s): {exc}") from exc
        except BaseException:  # Ctrl-C
            engine.abort()
            raise
        engine.started_s = time.perf_counter() - started
        return engine

    @classmethod
    def connect(cls, address: str, *, wait_for_workers: int = 1, timeout_s: float = 60.0) -> Engine:
        """Join a running scheduler (``tcp://HOST:8786``) and wait until it has ``wait_for_workers``."""
        from distributed import Client

        started = time.perf_counter()
        try:
            client = Client(address, timeout=timeout_s)
            if wait_for_workers:
                client.wait_for_workers(wait_for_workers, timeout=timeout_s)
        except Exception as exc:
            raise EngineError(f"cannot use the Dask scheduler at {address}: {exc}") from exc
        return cls(client, None, started_s=time.perf_counter() - started)

    # -- facts -----------------------------------------------------------------------
    @property
    def address(self) -> str:
        return str(self.client.scheduler.address)

    def workers(self) -> dict[str, int]:
        """Worker address -> threads."""
        info = self.client.scheduler_info(n_workers=-1)
        return {addr: int(w.get("nthreads", 1)) for addr, w in info.get("workers", {}).items()}

    def slots(self) -> int:
        """Tasks that can run at once (the workers' threads)."""
        return max(1, sum(self.workers().values()))

    def describe(self) -> str:
        kind = "local cluster" if self.cluster is not None else "scheduler"
        return f"{kind} {self.address}, {len(self.workers())} worker(s), {self.slots()} slot(s)"

    # -- work ------------------------------------------------------------------------
    def map(
        self,
        fn: Callable[[T], R],
        items: Sequence[T],
        *,
        keys: Sequence[str] | None = None,
        description: str = "tasks",
        on_done: Callable[[TaskOutcome[R]], None] | None = None,
        console: Console | None = None,
        show_progress: bool = True,
        retries: int = 0,
    ) -> list[TaskOutcome[R]]:
        """Run ``fn(item)`` for every item (``fn`` and the items must pickle);
        outcomes in item order. ``on_done`` sees each outcome as it arrives
        (in completion order, on the calling thread)."""
        from distributed import as_completed

        if keys is not None and len(keys) != len(items):
            raise ValueError("one key per item")
        if not items:
            return []
        names = list(keys) if keys is not None else [f"{description}-{i}" for i in range(len(items))]
        if len(set(names)) != len(names):
            raise ValueError("task keys must be unique")
        token = f"{int(time.time() * 1000):x}-{os.getpid()}"
        outcomes: list[TaskOutcome[R] | None] = [None] * len(items)
        submitted: dict[Any, tuple[int, float]] = {}
        futures = []
        for i, (item, name) in enumerate(zip(items, names)):
            fut = self.client.submit(_timed_call, fn, item, key=f"{name}-{token}", pure=False, retries=retries)
            submitted[fut] = (i, time.perf_counter())
            futures.append(fut)
        failed = 0
        here = f"{socket.gethostname()}:{os.getpid()}"
        arrived = [0]
        with _progress(console, show_progress) as prog, activity(lambda: f"{description}: {arrived[0]} of {len(items)} finished"):
            task = prog.add_task(description, total=len(items))
            for fut in as_completed(futures):
                arrived[0] += 1
                i, t0 = submitted[fut]
                out: TaskOutcome[R] = TaskOutcome(i, names[i])
                try:
                    ok, value, run_s, where, warned = fut.result()
                except Exception as exc:  # noqa: BLE001 - the worker died or the result did not arrive
                    out.error = f"{type(exc).__name__}: {exc}"
                else:
                    if where != here:  # a worker process's count (a thread of this process: this process counted them already)
                        add_remote(warned)
                    out.run_s, out.worker = run_s, where
                    if ok:
                        out.value = value
                    else:
                        out.error = str(value)
                out.round_trip_s = time.perf_counter() - t0
                fut.release()
                outcomes[i] = out
                if not out.ok:
                    failed += 1
                    prog.update(task, description=f"{description} ([red]{failed} failed[/red])")
                prog.advance(task)
                if on_done is not None:
                    on_done(out)
        return [o for o in outcomes if o is not None]

    # -- end ---------------------------------------------------------------------------
    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self.client is not None:
                self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def abort(self) -> None:
        """Ctrl-C: end a local cluster's worker processes at once (SIGKILL; the
        runs they held are abandoned, a sweep's journal keeps every finished
        one), then close. A graceful close waits for the workers' running
        tasks and took ~4 s; a remote scheduler's workers are its own (closing
        the client releases this client's tasks there)."""
        if self.cluster is not None and not self._closed:
            _quiet(("distributed", "tornado"))  # the connections the kills close are no one's problem: not logged
            for nanny in list(getattr(self.cluster, "workers", {}).values()):
                pid = getattr(nanny, "pid", None)
                if pid:
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
        self.close()

    def __enter__(self) -> Engine:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            self.abort()
        self.close()


def _quiet(packages: Sequence[str]) -> None:
    """Silence every logger of ``packages`` (Dask configures its own, child by child)."""
    for name in list(logging.root.manager.loggerDict):
        if any(name == p or name.startswith(p + ".") for p in packages):
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    for p in packages:
        logging.getLogger(p).setLevel(logging.CRITICAL + 1)


def _progress(console: Console | None, show: bool) -> Progress:
    console = console or Console(stderr=True)
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TextColumn("eta"),
        TimeRemainingColumn(),
        console=console,
        transient=False,
        disable=not (show and console.is_terminal),
    )


# --------------------------------------------------------------------------- the process's engine

_LOCK = threading.Lock()
_CURRENT: list[Engine] = []
_SCOPES: list[_Scope] = []
_OWNED: list[Engine] = []


@dataclass
class _Scope:
    scheduler: str | None
    workers: int | None
    engine: Engine | None = None

    def get(self) -> Engine:
        if self.engine is None:
            self.engine = Engine.connect(self.scheduler) if self.scheduler else Engine.local(self.workers)
        return self.engine


def current_engine() -> Engine:
    """The engine installed by :func:`use_engine`, else the one of the innermost :func:`engine_scope`
    (started on first use), else a local one started on first use and closed at exit."""
    with _LOCK:
        if _CURRENT:
            return _CURRENT[-1]
        if _SCOPES:
            return _SCOPES[-1].get()
        if not _OWNED or _OWNED[0]._closed:
            _OWNED[:] = [Engine.local()]
            atexit.register(_OWNED[0].close)
        return _OWNED[0]


@contextmanager
def use_engine(engine: Engine) -> Iterator[Engine]:
    """Make ``engine`` the one :func:`current_engine` returns inside the block."""
    with _LOCK:
        _CURRENT.append(engine)
    try:
        yield engine
    finally:
        with _LOCK:
            _CURRENT.remove(engine)


@contextmanager
def engine_scope(scheduler: str | None = None, workers: int | None = None) -> Iterator[None]:
    """Inside the block :func:`current_engine` is the scheduler at ``scheduler`` (or a local cluster of
    ``workers``), connected or started only if something asks for it, and closed at the end."""
    scope = _Scope(scheduler, workers)
    with _LOCK:
        _SCOPES.append(scope)
    try:
        yield
    except KeyboardInterrupt:
        if scope.engine is not None:
            scope.engine.abort()
        raise
    finally:
        with _LOCK:
            _SCOPES.remove(scope)
        if scope.engine is not None:
            scope.engine.close()
