"""Memory that grows with a run's length is a leak even when it is bounded
late: a latency tracker's ring is resident from its construction, so filling
it (5.5 minutes of a 200 Hz loop) adds nothing a process's RSS would show."""

from __future__ import annotations

import gc
import os

from service_kit.runtime import LatencyTracker

TRACKERS = 8
CAPACITY = 65536


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def test_a_latency_tracker_is_resident_when_built_and_does_not_grow_as_it_fills() -> None:
    gc.collect()
    before = _rss_bytes()
    trackers = [LatencyTracker(CAPACITY) for _ in range(TRACKERS)]
    built = _rss_bytes()
    ring_bytes = TRACKERS * CAPACITY * 8
    assert built - before >= 0.9 * ring_bytes  # every page of every ring is in memory now
    for tracker in trackers:
        for i in range(CAPACITY + 100):  # past a full ring: the oldest samples are overwritten
            tracker.add(1e-3 + i * 1e-9)
    gc.collect()
    grown = _rss_bytes() - built
    assert grown < 0.1 * ring_bytes, f"filling the rings grew the process by {grown} bytes ({grown / ring_bytes:.0%} of the rings)"
    assert all(t.count == CAPACITY + 100 and t.values().size == CAPACITY for t in trackers)
