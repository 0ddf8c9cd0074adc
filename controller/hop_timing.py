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
* ``irq_to_controller``: interrupt published -> received by the controller;
* ``irq_to_applied``: received -> applied at a tick.

The stamps go into preallocated ``array('q')`` rings (no allocation, no
numpy call on the tick path); percentiles are computed only when health
or the summary asks. :meth:`HopTimer.blame_tick` and
:meth:`HopTimer.blame_batch` name the hop that ate a missed budget.
"""

from __future__ import annotations

from array import array

import numpy as np

from protocol.messages import LatencyStats

TICK_HOPS = ("wakeup", "sync_to_tpdo", "tick_compute")
BATCH_HOPS = ("batch_to_dsp", "dsp_compute", "irq_to_controller", "irq_to_applied")
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
        p50, p99, p999 = np.percentile(data, [50.0, 99.0, 99.9])
        return LatencyStats(count=self.n, p50=float(p50), p99=float(p99), p999=float(p999), max=self.max * 1e-9)


class HopTimer:
    """The per-hop rings and the last tick's and batch's hops (for blame)."""

    def __init__(self, capacity: int = 65536) -> None:
        self.rings = {name: HopRing(capacity) for name in HOPS}
        self._wakeup = self.rings["wakeup"]
        self._s2t = self.rings["sync_to_tpdo"]
        self._compute = self.rings["tick_compute"]
        self.last_tick: tuple[int, int, int] = (0, 0, 0)
        self.last_batch: dict[str, int] = {}

    def tick(self, wakeup_ns: int, sync_ns: int, tpdo_ns: int, done_ns: int) -> None:
        """One tick: SYNC lateness (ns, -1 = not measured), SYNC sent, TPDO in, tick done (stopwatch ns)."""
        s2t = tpdo_ns - sync_ns
        comp = done_ns - tpdo_ns
        if wakeup_ns >= 0:
            self._wakeup.add(wakeup_ns)
        self._s2t.add(s2t)
        self._compute.add(comp)
        self.last_tick = (max(0, wakeup_ns), s2t, comp)

    def batch(self, sent_unix_s: float, irq_unix_s: float, compute_s: float, received_unix_s: float, applied_unix_s: float) -> None:
        """One interrupt applied: the batch path's hops from the stamps both sides took."""
        hops = {
            "batch_to_dsp": round((irq_unix_s - compute_s - sent_unix_s) * 1e9),
            "dsp_compute": round(compute_s * 1e9),
            "irq_to_controller": round((received_unix_s - irq_unix_s) * 1e9),
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

    def stats(self) -> dict[str, LatencyStats]:
        """``hop_<name>`` percentiles of every hop measured at least once."""
        return {f"hop_{name}": ring.stats() for name, ring in self.rings.items() if ring.n}
