"""service_kit.realtime: measures applied where permitted, reported where not."""

from __future__ import annotations

import os
import threading

import pytest

from service_kit.realtime import apply_realtime, parse_cpus


def test_parse_cpus() -> None:
    assert parse_cpus("") == () and parse_cpus("1") == (1,) and parse_cpus("0-2,5") == (0, 1, 2, 5)
    with pytest.raises(ValueError, match="cpu_affinity"):
        parse_cpus("one")


def test_measures_on_a_thread_of_their_own_fall_back_cleanly() -> None:
    """On a thread (SCHED_FIFO and affinity are per thread on Linux): pinning to a
    CPU we have works, to one we lack is reported, FIFO either works or is
    reported; nothing raises. The FIFO thread sleeps at once and ends."""
    out: dict[str, object] = {}

    def body() -> None:
        have = sorted(os.sched_getaffinity(0))
        out["ok"] = apply_realtime(priority=1, cpu_affinity=str(have[0]))
        out["missing"] = apply_realtime(priority=0, cpu_affinity="4095", freeze_gc=False)

    t = threading.Thread(target=body)
    t.start()
    t.join(10)
    ok, missing = out["ok"], out["missing"]
    assert ok.cpus and ok.gc_frozen  # type: ignore[union-attr]
    assert ok.fifo_priority == 1 or any("SCHED_FIFO" in n for n in ok.notes)  # type: ignore[union-attr]
    assert missing.cpus == () and missing.fifo_priority == 0 and any("not available" in n for n in missing.notes)  # type: ignore[union-attr]
    assert ok.as_counters()["rt_gc_frozen"] == 1  # type: ignore[union-attr]
