"""service_kit.runtime.sorted_percentiles equals numpy's percentile (its
default linear method) bit for bit, and LatencyTracker's stats with it."""

from __future__ import annotations

import numpy as np
import pytest

from service_kit.runtime import LatencyTracker, sorted_percentiles

QS = (0.0, 1.0, 25.0, 50.0, 90.0, 99.0, 99.9, 99.99, 100.0)


@pytest.mark.parametrize("n", [1, 2, 3, 7, 10, 99, 100, 101, 999, 1000, 4096, 65536])
def test_equals_numpy_percentile_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    for kind in range(6):
        if kind == 0:
            data = rng.exponential(size=n) * 10 ** rng.uniform(-7, -2)
        elif kind == 1:
            data = rng.standard_normal(n)
        elif kind == 2:
            data = np.round(rng.uniform(0, 1e-3, n), 6)  # ties
        elif kind == 3:
            data = np.full(n, 1.5e-4)
        elif kind == 4:
            data = np.sort(rng.uniform(size=n))[::-1].copy()
        else:
            data = rng.integers(0, 1 << 40, n).astype(np.float64) * 1e-9  # ns stamps in seconds, as the hop rings hold
        expected = np.percentile(data, QS)
        got = sorted_percentiles(data.copy(), QS)
        assert np.array_equal(np.array(got), expected), (n, kind)


def test_tracker_stats_are_numpys_percentiles_of_its_window() -> None:
    tracker = LatencyTracker(capacity=1000)
    rng = np.random.default_rng(0)
    samples = rng.exponential(size=2500) * 1e-4
    for x in samples[:10]:
        tracker.add(float(x))
    first = tracker.stats()
    assert tracker.stats() is first  # nothing new: the same answer, not recomputed
    for x in samples[10:]:
        tracker.add(float(x))
    stats = tracker.stats()
    window = samples[-1000:]  # the ring keeps the latest capacity samples (in ring order)
    p50, p99, p999 = np.percentile(window, [50.0, 99.0, 99.9])
    assert (stats.p50, stats.p99, stats.p999) == (p50, p99, p999)
    assert stats.count == 2500 and stats.max == samples.max()
