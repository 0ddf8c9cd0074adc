"""What Linux offers a real-time loop, applied where permitted, with a clean
fallback where not: ``SCHED_FIFO`` (``os.sched_setscheduler``), CPU affinity
(``os.sched_setaffinity``), a PM QoS bound on the CPUs' wake-up latency
(``/dev/cpu_dma_latency``, as cyclictest holds it) and ``gc.freeze()``
(objects alive at the start of the loop leave the collector's generations,
so its pauses stay short).

SCHED_FIFO, affinity and the wake-up latency are opt-in (settings
``realtime``: ``priority``, ``cpus`` and ``cpu_latency_us``): a FIFO thread that never sleeps would starve a shared
machine. With SCHED_FIFO, the interpreter's GIL switch interval drops to
``GIL_SWITCH_INTERVAL_S``: a FIFO loop that wants the GIL back from one of
zenoh's callback threads would otherwise wait out CPython's default 5 ms.
The loop's thread takes FIFO with ``SCHED_RESET_ON_FORK``: a thread created
from it later starts on the normal scheduler. zenoh creates threads lazily
(its runtimes' workers, the first time a path needs them): without the flag
one inherited the loop's FIFO priority, and at the controller's first batch
it spent 12-19 ms at that priority mapping (``mlock``) a shared-memory
segment while the loop waited (docs/timing.md). The process's other threads
(zenoh's runtime) stay on the normal scheduler: moved to FIFO they ran into
the kernel's real-time throttling (50 ms stalls each second) in the
acceptance runs (docs/timing.md). The loop's own helper threads (health, TF
download) run FIFO one level below it: the loop asks :func:`helper_priority`
before starting one, and the helper takes it first thing
(:func:`lower_current_thread`), since threads at one FIFO priority are not
time-sliced.
Each measure reports whether it took effect; the services put that
into their health counters and log it, and ``ralf-hil up`` prints it.
"""

from __future__ import annotations

import gc
import logging
import os
import struct
import sys
from dataclasses import dataclass

from protocol.setting_groups import parse_cpus  # the one parser: settings refuse a bad list at load

log = logging.getLogger(__name__)

GIL_SWITCH_INTERVAL_S = 0.0002
"""The GIL switch interval under SCHED_FIFO (CPython's default is 5 ms)."""

CPU_LATENCY_DEVICE = "/dev/cpu_dma_latency"
"""Linux PM QoS: while a process holds this open with a value written, no
CPU enters an idle state whose exit latency exceeds that many µs."""
_cpu_latency_fd: int | None = None
_cpu_latency_us: int = -1

_RESET_ON_FORK: int = getattr(os, "SCHED_RESET_ON_FORK", 0)
"""Linux: or-ed into a policy, threads created by the thread start on the
normal scheduler instead of inheriting its real-time policy (and
``sched_getscheduler`` returns it or-ed in)."""


def _fifo_priority_of_current_thread() -> int:
    """The calling thread's SCHED_FIFO priority (0: not FIFO)."""
    try:
        if os.sched_getscheduler(0) & ~_RESET_ON_FORK != os.SCHED_FIFO:
            return 0
        return int(os.sched_getparam(0).sched_priority)
    except (AttributeError, OSError):
        return 0


def _set_fifo(priority: int) -> None:
    """SCHED_FIFO at ``priority`` for the calling thread, threads it creates
    later starting on the normal scheduler (``SCHED_RESET_ON_FORK`` where the
    system has it)."""
    param = os.sched_param(priority)
    if _RESET_ON_FORK:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO | _RESET_ON_FORK, param)
            return
        except OSError:
            pass
    os.sched_setscheduler(0, os.SCHED_FIFO, param)


@dataclass(frozen=True)
class RealtimeMeasures:
    """Which measures are in effect for the calling thread."""

    fifo_priority: int = 0
    """SCHED_FIFO priority in effect (0: the normal scheduler)."""
    switch_interval_s: float = 0.0
    """The GIL switch interval set (0: left at the interpreter's default)."""
    cpus: tuple[int, ...] = ()
    """CPUs the thread is pinned to (empty: not pinned)."""
    gc_frozen: bool = False
    cpu_latency_us: int = -1
    """The CPU wake-up latency bound held through PM QoS (-1: the system's idle states left alone)."""
    notes: tuple[str, ...] = ()
    """Why a requested measure did not take effect."""

    def as_counters(self) -> dict[str, int]:
        return {
            "rt_fifo_priority": self.fifo_priority,
            "rt_switch_interval_us": round(self.switch_interval_s * 1e6),
            "rt_pinned_cpus": len(self.cpus),
            "rt_gc_frozen": int(self.gc_frozen),
            "rt_cpu_latency_us": self.cpu_latency_us,
        }

    def describe(self) -> str:
        parts = [f"SCHED_FIFO {self.fifo_priority}" if self.fifo_priority else "normal scheduler"]
        if self.switch_interval_s:
            parts.append(f"GIL switch interval {self.switch_interval_s * 1e3:g} ms")
        parts.append(f"pinned to CPU {','.join(map(str, self.cpus))}" if self.cpus else "not pinned")
        parts.append("gc frozen" if self.gc_frozen else "gc not frozen")
        if self.cpu_latency_us >= 0:
            parts.append(f"CPU wake-up latency <= {self.cpu_latency_us} us (PM QoS)")
        return ", ".join(parts) + (f" ({'; '.join(self.notes)})" if self.notes else "")


def hold_cpu_latency(us: int, device: str | None = None) -> int:
    """Ask PM QoS to keep every CPU's wake-up latency within ``us`` µs for as
    long as this process lives (``/dev/cpu_dma_latency``, root; the request
    ends when the process exits). 0 keeps idle CPUs polling instead of
    halting: on a virtual machine a halted vCPU costs a VM exit and entry at
    every wake-up, which the rig pays twice per control tick (SYNC to the
    plant, TPDO1 back) and a sleep-only loop once. Returns the bound in
    effect (the lowest asked for in this process); raises OSError where
    refused."""
    global _cpu_latency_fd, _cpu_latency_us
    if _cpu_latency_fd is not None and 0 <= _cpu_latency_us <= us:
        return _cpu_latency_us
    fd = os.open(device or CPU_LATENCY_DEVICE, os.O_WRONLY)
    try:
        os.write(fd, struct.pack("i", us))
    except OSError:
        os.close(fd)
        raise
    if _cpu_latency_fd is not None:
        os.close(_cpu_latency_fd)
    _cpu_latency_fd, _cpu_latency_us = fd, us
    return us


def apply_realtime(
    priority: int = 0, cpu_affinity: str = "", freeze_gc: bool = True, *, whole_process: bool = False, cpu_latency_us: int = -1
) -> RealtimeMeasures:
    """Apply the measures to the calling thread; never raises for a measure
    the system refuses (it is reported in ``notes`` instead).

    ``whole_process``: a service's loop thread in a process of its own. With
    SCHED_FIFO granted, the process-wide GIL switch interval drops (see the
    module's docstring). ``cpu_latency_us`` >= 0: :func:`hold_cpu_latency`
    (process-wide, opt-in: idle CPUs then poll instead of halting)."""
    notes: list[str] = []
    fifo = 0
    if priority > 0:
        try:
            lo, hi = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
            prio = min(max(priority, lo), hi)
            _set_fifo(prio)
            fifo = prio
        except (AttributeError, OSError) as exc:
            notes.append(f"SCHED_FIFO refused: {exc}")
    switch = 0.0
    if fifo and whole_process:
        switch = min(sys.getswitchinterval(), GIL_SWITCH_INTERVAL_S)
        sys.setswitchinterval(switch)
    cpus: tuple[int, ...] = ()
    wanted = parse_cpus(cpu_affinity)
    if wanted:
        try:
            available = os.sched_getaffinity(0)
            chosen = {c for c in wanted if c in available}
            if not chosen:
                notes.append(f"CPUs {wanted} not available (have {sorted(available)})")
            else:
                os.sched_setaffinity(0, chosen)
                cpus = tuple(sorted(chosen))
        except (AttributeError, OSError) as exc:
            notes.append(f"affinity refused: {exc}")
    latency = -1
    if cpu_latency_us >= 0:
        try:
            latency = hold_cpu_latency(cpu_latency_us)
        except OSError as exc:
            notes.append(f"PM QoS CPU latency refused: {exc}")
    frozen = False
    if freeze_gc:
        gc.collect()
        gc.freeze()
        frozen = True
    measures = RealtimeMeasures(fifo_priority=fifo, switch_interval_s=switch, cpus=cpus, gc_frozen=frozen, cpu_latency_us=latency, notes=tuple(notes))
    log.info("real-time measures: %s", measures.describe())
    return measures


def helper_priority() -> int:
    """Called by a loop about to start a helper thread (health, TF download):
    the FIFO priority the helper is to take, one level below the caller's
    (0: the caller is not FIFO, the helper stays on the normal scheduler).
    Pass it to :func:`lower_current_thread` in the helper."""
    prio = _fifo_priority_of_current_thread()
    if not prio:
        return 0
    try:
        return max(prio - 1, os.sched_get_priority_min(os.SCHED_FIFO))
    except (AttributeError, OSError):
        return 0


def lower_current_thread(priority: int) -> bool:
    """A helper thread (health, TF download) started by a FIFO loop runs one
    FIFO level below the loop (threads at the same FIFO priority are not
    time-sliced, so the helper would hold the loop's core until it blocks).
    ``priority``: what the loop's :func:`helper_priority` gave when it started
    the helper (the loop's FIFO is not inherited: it resets on fork); 0 leaves
    the thread on the normal scheduler. Called first thing in the helper;
    returns True when the thread now runs FIFO below its loop."""
    try:
        if priority <= 0:
            return False
        _set_fifo(priority)
        return True
    except (AttributeError, OSError):
        return False
