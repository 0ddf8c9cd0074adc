"""What Linux offers a real-time loop, applied where permitted, with a clean
fallback where not: ``SCHED_FIFO`` (``os.sched_setscheduler``), CPU affinity
(``os.sched_setaffinity``) and ``gc.freeze()`` (objects alive at the start of
the loop leave the collector's generations, so its pauses stay short).

SCHED_FIFO and affinity are opt-in (settings ``rt_priority`` and
``cpu_affinity``): a FIFO thread that never sleeps would starve a shared
machine. Each measure reports whether it took effect; the services put that
into their health counters and log it, and ``ralf-hil up`` prints it.
"""

from __future__ import annotations

import gc
import logging
import os
from dataclasses import dataclass

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RealtimeMeasures:
    """Which measures are in effect for the calling thread."""

    fifo_priority: int = 0
    """SCHED_FIFO priority in effect (0: the normal scheduler)."""
    cpus: tuple[int, ...] = ()
    """CPUs the thread is pinned to (empty: not pinned)."""
    gc_frozen: bool = False
    notes: tuple[str, ...] = ()
    """Why a requested measure did not take effect."""

    def as_counters(self) -> dict[str, int]:
        return {"rt_fifo_priority": self.fifo_priority, "rt_pinned_cpus": len(self.cpus), "rt_gc_frozen": int(self.gc_frozen)}

    def describe(self) -> str:
        parts = [f"SCHED_FIFO {self.fifo_priority}" if self.fifo_priority else "normal scheduler"]
        parts.append(f"pinned to CPU {','.join(map(str, self.cpus))}" if self.cpus else "not pinned")
        parts.append("gc frozen" if self.gc_frozen else "gc not frozen")
        return ", ".join(parts) + (f" ({'; '.join(self.notes)})" if self.notes else "")


def parse_cpus(text: str) -> tuple[int, ...]:
    """``"1"``, ``"0,1"`` or ``"0-1"`` -> CPU numbers; empty -> ()."""
    cpus: list[int] = []
    for part in (p.strip() for p in text.split(",") if p.strip()):
        lo, sep, hi = part.partition("-")
        if not lo.isdigit() or (sep and not hi.isdigit()):
            raise ValueError(f"cpu_affinity {text!r}: expected CPU numbers like 1 or 0,1 or 0-1")
        cpus.extend(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    return tuple(sorted(set(cpus)))


def apply_realtime(priority: int = 0, cpu_affinity: str = "", freeze_gc: bool = True) -> RealtimeMeasures:
    """Apply the measures to the calling thread; never raises for a measure
    the system refuses (it is reported in ``notes`` instead)."""
    notes: list[str] = []
    fifo = 0
    if priority > 0:
        try:
            lo, hi = os.sched_get_priority_min(os.SCHED_FIFO), os.sched_get_priority_max(os.SCHED_FIFO)
            prio = min(max(priority, lo), hi)
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
            fifo = prio
        except (AttributeError, OSError) as exc:
            notes.append(f"SCHED_FIFO refused: {exc}")
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
    frozen = False
    if freeze_gc:
        gc.collect()
        gc.freeze()
        frozen = True
    measures = RealtimeMeasures(fifo_priority=fifo, cpus=cpus, gc_frozen=frozen, notes=tuple(notes))
    log.info("real-time measures: %s", measures.describe())
    return measures
