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


PROBE = """
import ctypes, sys
from service_kit.runtime import fix_malloc_threshold
libc = ctypes.CDLL(None)
class MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks", "fordblks", "keepcost")]
libc.mallinfo2.restype = MallInfo2
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]
if sys.argv[1] == "fixed":
    assert fix_malloc_threshold()
libc.free(libc.malloc(4 << 20))  # a large block freed: glibc's dynamic threshold would rise to 4 MiB
before = libc.mallinfo2().hblks
block = libc.malloc(512 << 10)  # a mid-size block
print(libc.mallinfo2().hblks - before)
libc.free(block)
"""


def test_the_services_malloc_threshold_stays_fixed_so_mid_size_blocks_leave_no_heap_holes() -> None:
    """What grew the controller's RSS ~0.6 MB/min with its bytes in use flat: after
    one large block is freed, glibc puts mid-size blocks on the heap (fragmenting
    it); every service fixes the threshold at start (``run_service``)."""
    import subprocess
    import sys

    def mmapped(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", PROBE, mode], capture_output=True, text=True, timeout=60, check=True)
        return int(out.stdout.strip())

    assert mmapped("default") == 0  # glibc's dynamic threshold: the 512 KiB block came from the heap
    assert mmapped("fixed") == 1  # fixed at 64 KiB: mapped, and returned to the system when freed
