"""Per-hop timestamps of the controller's two paths, cheap enough for every tick.

Tick path (every sample; wall stamps from the stopwatch in integer ns,
simulated time = tick x Ts):

* ``wakeup``: the SYNC's lateness against its deadline ``t0 + k Ts``
  (real time only; the scheduler's wake-up);
* ``sync_to_tpdo``: SYNC sent -> TPDO1 received (CAN out, the plant's
  sampling, CAN back);
* ``tick_compute``: TPDO1 received -> tick done (control law, RPDO1 out,
  batch append, bookkeeping).

Batch path (every batch; the DSP's stamps travel in its interrupt, so
nothing is added to the DSP's messages):

* ``batch_to_dsp``: batch sent -> the DSP starts computing
  (``Interrupt.wall_time_s - compute_time_s`` against the batch's
  ``wall_time_s``, both Unix time: exact on one host, within the clock
  offset across hosts);
* ``dsp_compute``: ``Interrupt.compute_time_s``;
* ``dsp_hold``: real time only: the rest of the DSP's emulated latency
  (the C40's 100 ms), for which the board holds a computed interrupt
  (``max(0, latency - compute)``; lockstep applies it in ticks instead);
* ``irq_to_controller``: interrupt raised -> received by the controller;
* ``irq_to_applied``: received -> applied at a tick.

The tick path's four raw stamps go into one preallocated ``array('q')``
ring, written inline by the loop (four item stores, no call, no
allocation); the batch path's hops into rings of their own. Differences,
percentiles and maxima are computed only when health or a report asks, over
the last ``capacity`` ticks (the tick hops' ``max`` too). :meth:`HopTimer.blame_tick` and
:meth:`HopTimer.blame_batch` name the hop that ate a missed budget.
"""

from __future__ import annotations

from array import array

import numpy as np

from protocol.messages import LatencyStats
from service_kit.runtime import sorted_percentiles

TICK_HOPS = ("wakeup", "sync_to_tpdo", "tick_compute")
BATCH_HOPS = ("batch_to_dsp", "dsp_compute", "dsp_hold", "irq_to_controller", "irq_to_applied")
HOPS = TICK_HOPS + BATCH_HOPS


class HopRing:
    """The last ``capacity`` values of one hop, in integer ns; count and max over the run."""

    __slots__ = ("buf", "n", "max", "capacity")

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.buf = array("q", bytes(8 * capacity))
        self.n = 0
        self.max = 0

    def add(self, ns: int) -> None:
        if ns < 0:
            ns = 0
        self.buf[self.n % self.capacity] = ns
        self.n += 1
        if ns > self.max:
            self.max = ns

    def values_s(self) -> np.ndarray:
        data = np.frombuffer(self.buf, dtype=np.int64)[: min(self.n, self.capacity)]
        return data.astype(np.float64) * 1e-9

    def stats(self) -> LatencyStats:
        data = self.values_s()
        if data.size == 0:
            return LatencyStats(count=0, p50=0.0, p99=0.0, p999=0.0, max=0.0)
        p50, p99, p999 = sorted_percentiles(data)  # np.percentile's values without its GIL-holding partition
        return LatencyStats(count=self.n, p50=p50, p99=p99, p999=p999, max=self.max * 1e-9)


class HopTimer:
    """The tick path's raw stamps, the batch path's rings, and blame.

    The loop writes tick ``i``'s stamps itself (see :meth:`tick`, which does
    the same, for callers off the hot path): ``raw[4 j] = wakeup lateness
    (ns, -1 = not measured)``, ``raw[4 j + 1] = SYNC sent``, ``raw[4 j + 2] =
    TPDO1 in``, ``raw[4 j + 3] = tick done`` (stopwatch ns) with ``j = n %
    capacity``, then ``n += 1``."""

    def __init__(self, capacity: int = 65536) -> None:
        self.capacity = capacity
        self.raw = array("q", bytes(8 * 4 * capacity))
        self.n = 0
        self.rings = {name: HopRing(capacity) for name in BATCH_HOPS}
        self.last_batch: dict[str, int] = {}

    def tick(self, wakeup_ns: int, sync_ns: int, tpdo_ns: int, done_ns: int) -> None:
        """One tick's stamps (what the loop writes inline)."""
        j = (self.n % self.capacity) << 2
        raw = self.raw
        raw[j] = wakeup_ns
        raw[j + 1] = sync_ns
        raw[j + 2] = tpdo_ns
        raw[j + 3] = done_ns
        self.n += 1

    @property
    def last_tick(self) -> tuple[int, int, int]:
        """The last tick's (wakeup, sync_to_tpdo, tick_compute) in ns."""
        if not self.n:
            return (0, 0, 0)
        j = ((self.n - 1) % self.capacity) << 2
        w, s, t, d = self.raw[j : j + 4]
        return (max(0, w), t - s, d - t)

    def tick_hops_s(self) -> dict[str, np.ndarray]:
        """The tick hops (s) of the last ``capacity`` ticks, in tick order within the ring."""
        m = min(self.n, self.capacity)
        r = np.frombuffer(self.raw, dtype=np.int64)[: 4 * m].reshape(m, 4)
        wake = r[:, 0]
        return {
            "wakeup": wake[wake >= 0].astype(np.float64) * 1e-9,
            "sync_to_tpdo": np.maximum(r[:, 2] - r[:, 1], 0).astype(np.float64) * 1e-9,
            "tick_compute": np.maximum(r[:, 3] - r[:, 2], 0).astype(np.float64) * 1e-9,
        }

    def batch(self, sent_unix_s: float, irq_unix_s: float, compute_s: float, hold_s: float, received_unix_s: float, applied_unix_s: float) -> None:
        """One interrupt applied: the batch path's hops from the stamps both sides took
        (``irq_unix_s``: the interrupt's ``wall_time_s``, stamped when its computation ended)."""
        hops = {
            "batch_to_dsp": round((irq_unix_s - compute_s - sent_unix_s) * 1e9),
            "dsp_compute": round(compute_s * 1e9),
            "dsp_hold": round(hold_s * 1e9),
            "irq_to_controller": round((received_unix_s - irq_unix_s - hold_s) * 1e9),
            "irq_to_applied": round((applied_unix_s - received_unix_s) * 1e9),
        }
        for name, ns in hops.items():
            self.rings[name].add(ns)
        self.last_batch = hops

    def blame_tick(self) -> str:
        """The tick hop that took longest in the last tick, with its share."""
        name, ns = max(zip(TICK_HOPS, self.last_tick), key=lambda p: p[1])
        total = sum(self.last_tick)
        return f"{name} {ns / 1e6:.2f} ms of {total / 1e6:.2f} ms"

    def blame_batch(self, hops: dict[str, int] | None = None) -> str | None:
        h = hops if hops is not None else self.last_batch
        if not h:
            return None
        name = max(h, key=lambda k: h[k])
        return f"{name} {h[name] / 1e6:.2f} ms of {sum(max(0, v) for v in h.values()) / 1e6:.2f} ms"

    def values_s(self) -> dict[str, np.ndarray]:
        """Every hop measured at least once: its values (s)."""
        out = {k: v for k, v in self.tick_hops_s().items() if v.size}
        out.update({name: ring.values_s() for name, ring in self.rings.items() if ring.n})
        return out

    def stats(self) -> dict[str, LatencyStats]:
        """``hop_<name>`` percentiles of every hop measured at least once."""
        out = {}
        for name, v in self.tick_hops_s().items():
            if v.size:
                top = float(v.max())
                p50, p99, p999 = sorted_percentiles(v)  # sorts v (a fresh array)
                out[f"hop_{name}"] = LatencyStats(count=int(v.size) if self.n <= self.capacity else self.n, p50=p50, p99=p99, p999=p999, max=top)
        out.update({f"hop_{name}": ring.stats() for name, ring in self.rings.items() if ring.n})
        return out
