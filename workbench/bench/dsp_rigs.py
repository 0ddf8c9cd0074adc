"""``ralf-hil bench --only dsp-rigs``: how many 200 Hz rigs one DSP process serves.

One ``python -m dsp_service`` child serves ``rigs`` rig ids at once
(``RALF_SERVE_RIGS``; N = 2048, emulated latency 0, real time). This process
acts as the rigs' controllers: each rig sends a batch of ``l`` samples every
batch period ``l / 200 Hz`` (when its block is empty), and the time from
sending a batch to its interrupt arriving is its turnaround; the budget is
the batch period (the thesis's deadline: the CPU's next batch is due then).
Rungs of 1, 4, 16, ... rigs run in turn against the same DSP process; a rung
is *served* when no rig missed (no turnaround over the budget, no batch due
while its block was still full). The DSP process's CPU time per batch,
measured over each rung, gives the figure a loaded core would reach
(``rigs_per_core_by_cpu``): an extrapolation from measured numbers, labelled
as such. Then one rig at 1 kHz with N = 8192, driven the same way with
batches of l = 1, 2 and 5 samples (batch periods of 1, 2 and 5 ms), each
against a DSP process of its own: the shortest batch period it sustains
through zenoh, and its step's time alone. A driven rig takes an interrupt
as its block emptied, as the controller does. Nothing here asserts a time.
"""

from __future__ import annotations

import math
import os
import queue
import sys
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocol.batch_codec import SampleBatch, encode_batch
from protocol.keys import Keys
from protocol.messages import BlockFlag, Interrupt, decode
from workbench.bench.pingers import zenoh_session
from workbench.bench.procs import BenchError, Child, clean_env, private_rig_id
from workbench.bench.stats import summarize
from workbench.launcher import free_tcp_port

RATE_HZ = 200.0
FFT_WIDTH = 2048
BATCH = 30  #: DspSettings' default batch size: a 150 ms batch period at 200 Hz
FAST_RATE_HZ = 1000.0
FAST_FFT_WIDTH = 8192
FAST_BATCHES = (1, 2, 5)  #: l at 1 kHz: batch periods of 1, 2 and 5 ms (l = 1: a batch per sample)


@dataclass
class _Rig:
    keys: Keys
    seq: int = 0
    empty_for: int = -1  #: next_batch_seq of the latest empty flag
    sent_at: float | None = None
    next_due: float = 0.0
    tick: int = 0  #: first tick of the next batch (batches are contiguous whatever their size)
    turnaround: list[float] = field(default_factory=list)
    compute: list[float] = field(default_factory=list)
    full_when_due: int = 0


def _batch(rig: _Rig, n: int, rate_hz: float, seed: int) -> SampleBatch:
    """The rig's next batch of ``n`` samples, contiguous with its last."""
    rng = np.random.default_rng(seed * 1_000_003 + rig.seq)
    batch = SampleBatch(
        seq=rig.seq,
        first_tick=rig.tick,
        sample_rate_hz=rate_hz,
        sim_time_s=rig.tick / rate_hz,
        wall_time_s=time.time(),
        inputs=rng.standard_normal((2, n)),
        outputs=rng.standard_normal((2, n)),
    )
    rig.tick += n
    return batch


def _cpu_s(pid: int) -> float:
    """utime + stime of a process (Linux /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def bench_dsp_rigs(ctx: Any, result: dict[str, Any]) -> None:
    """The rungs above; results per rung and the largest rung served. Then one rig at
    1 kHz with N = 8192 for each batch size of :data:`FAST_BATCHES` (l = 1: a batch per
    sample, a 1 ms budget): the shortest batch period one DSP sustains at that width."""
    rungs = (1, 4, 16) if ctx.quick else (1, 4, 16, 32, 64)
    seconds = 2.0 if ctx.quick else 6.0
    result["config"] = {
        "rigs_served_by_the_process": max(rungs),
        "rungs": list(rungs),
        "seconds_per_rung": seconds,
        "fft_width": FFT_WIDTH,
        "batch": BATCH,
        "rate_hz": RATE_HZ,
        "budget_ms": BATCH / RATE_HZ * 1e3,
        "fast": {"rate_hz": FAST_RATE_HZ, "fft_width": FAST_FFT_WIDTH, "batches": list(FAST_BATCHES)},
    }
    m = result["measurements"]
    served, per_batch = _ladder(ctx, m, "", rungs, seconds, RATE_HZ, FFT_WIDTH, BATCH)
    m["rigs_per_core_by_cpu"] = {
        "kind": "scalar",
        "value": round(BATCH / RATE_HZ / per_batch[0], 1),
        "unit": "rigs",
        "note": f"extrapolated: batch period / DSP CPU time per batch at {per_batch[1]} rigs",
    }
    m["rigs_served"] = {
        "kind": "scalar",
        "value": served,
        "unit": "rigs",
        "note": f"largest rung with no late or missed interrupt (rungs {list(rungs)}, N = {FFT_WIDTH}, 200 Hz, l = {BATCH})",
    }
    shortest = None
    for batch in FAST_BATCHES:
        label = f"{FAST_RATE_HZ / 1e3:g} kHz N={FAST_FFT_WIDTH} l={batch}: "
        if _ladder(ctx, m, label, (1,), seconds, FAST_RATE_HZ, FAST_FFT_WIDTH, batch)[0] and shortest is None:
            shortest = batch
    m[f"{FAST_RATE_HZ / 1e3:g} kHz N={FAST_FFT_WIDTH}: shortest batch period served"] = {
        "kind": "scalar",
        "value": None if shortest is None else shortest / FAST_RATE_HZ * 1e3,
        "unit": "ms",
        "note": f"the smallest l of {list(FAST_BATCHES)} with no late or missed interrupt, through zenoh (the step alone: dsp_compute_p50_us)",
    }


def _ladder(
    ctx: Any, m: dict[str, Any], label: str, rungs: tuple[int, ...], seconds: float, rate_hz: float, fft_width: int, batch: int
) -> tuple[int, tuple[float, int]]:
    """One DSP process serving ``max(rungs)`` rigs, driven rung by rung; fills ``m``;
    returns the largest rung served and (DSP CPU s per batch, rigs) of the last rung."""
    total = max(rungs)
    base = private_rig_id("rigs")
    ids = [f"{base}-{i}" for i in range(total)]
    port = free_tcp_port()
    with ExitStack() as stack:
        dsp = stack.enter_context(
            Child([sys.executable, "-m", "dsp_service"], env=_dsp_env(ids, port, rate_hz, fft_width, batch), name="dsp-rigs", log_dir=ctx.log_dir)
        )
        session = zenoh_session(connect=[f"tcp/127.0.0.1:{port}"])
        stack.callback(session.close)
        driver = _Driver(session, stack, [_Rig(Keys(rig)) for rig in ids], rate_hz, batch)
        ctx.say(f"  one DSP process serving {total} rigs; waiting for their empty flags")
        deadline = driver.wait_empty(dsp)
        driver.fill(total, fft_width, deadline)
        driver.take(time.perf_counter() + 0.5)
        served = 0
        per_batch = (math.nan, 0)
        for k in rungs:
            cpu, wall, samples, late, behind = driver.rung(k, seconds, dsp)
            if not samples:
                raise BenchError(f"no interrupt in the rung of {k} rigs; {dsp.describe_failure()}")
            entry = _rung_entry(samples, driver.period, late, behind, cpu, wall, [c for r in driver.rigs[:k] for c in r.compute])
            m[f"{label}{k} rigs: batch_to_interrupt"] = entry
            ctx.say(
                f"  {label}{k:>3} rigs: {len(samples)} batches, p50 {entry['p50_us'] / 1e3:.2f} ms, p99 {entry['p99_us'] / 1e3:.2f} ms "
                f"(budget {driver.period * 1e3:g} ms), step p50 {entry['dsp_compute_p50_us'] / 1e3:.2f} ms, "
                f"late {late}, behind {behind}, DSP CPU {cpu / wall:.0%} of one core"
            )
            if late == 0 and behind == 0:
                served = k
            per_batch = (cpu / len(samples), k)
        driver.close()
    return served, per_batch


def _dsp_env(ids: list[str], port: int, rate_hz: float, fft_width: int, batch: int) -> dict[str, str]:
    """The DSP child's settings: every rig of ``ids`` served, no emulated latency."""
    return clean_env(
        {
            "RALF_RIG_ID": ids[0],
            "RALF_SERVE_RIGS": ",".join(ids[1:]),
            "RALF_ZENOH_MODE": "peer",
            "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}",
            "RALF_EMULATED_LATENCY_S": "0",
            "RALF_SAMPLE_RATE_HZ": str(rate_hz),
            "RALF_FFT_WIDTH": str(fft_width),
            "RALF_BATCH_SIZE": str(batch),
            "RALF_LOG_LEVEL": "WARNING",
        }
    )


def _rung_entry(samples: list[float], period: float, late: int, behind: int, cpu: float, wall: float, compute: list[float]) -> dict[str, Any]:
    """One rung's measurement: turnarounds against the batch period, and the DSP's CPU share."""
    summary = summarize(samples)
    return {
        "kind": "latency",
        **summary,
        "floor": "budget (batch period)",
        "floor_value_us": period * 1e6,
        "ratio": {"p99": float(summary["p99_us"]) / (period * 1e6)},
        "late": late,
        "behind": behind,
        "dsp_cpu_fraction": cpu / wall,
        "dsp_cpu_per_batch_us": cpu / len(samples) * 1e6,
        "dsp_compute_p50_us": float(np.median(compute)) * 1e6,
    }


class _Driver:
    """This process as the rigs' controllers: a batch per rig every batch period when
    its block is empty; the flags and interrupts handled as they arrive."""

    def __init__(self, session: Any, stack: ExitStack, rigs: list[_Rig], rate_hz: float, batch: int) -> None:
        self.rigs = rigs
        self.rate_hz = rate_hz
        self.batch = batch
        self.period = batch / rate_hz
        self.events: queue.SimpleQueue[tuple[int, str, bytes, float]] = queue.SimpleQueue()
        self.pubs = []
        perf = time.perf_counter
        for i, rig in enumerate(rigs):
            for kind, key in (("flag", rig.keys.flag), ("irq", rig.keys.interrupt)):

                def on_sample(sample: Any, i: int = i, kind: str = kind) -> None:
                    self.events.put((i, kind, sample.payload.to_bytes(), perf()))

                sub = session.declare_subscriber(key, on_sample)
                stack.callback(sub.undeclare)
            self.pubs.append(session.declare_publisher(rig.keys.batch))

    def take(self, until: float) -> None:
        """Handle events until ``until`` (perf time)."""
        while True:
            remaining = until - time.perf_counter()
            if remaining <= 0:
                return
            try:
                i, kind, payload, arrived = self.events.get(timeout=remaining)
            except queue.Empty:
                return
            rig = self.rigs[i]
            if kind == "flag":
                flag = decode(BlockFlag, payload)
                if flag.state == "empty":
                    rig.empty_for = max(rig.empty_for, flag.next_batch_seq)
            else:
                irq = decode(Interrupt, payload)
                if rig.sent_at is not None and irq.batch_seq == rig.seq - 1:
                    rig.turnaround.append(arrived - rig.sent_at)
                    rig.compute.append(irq.compute_time_s)
                    rig.sent_at = None
                    # the interrupt says the block is empty again, as the controller takes it
                    # (controller.dsp_link.DspLink.on_interrupt); the flag that follows says it too
                    rig.empty_for = max(rig.empty_for, irq.batch_seq + 1)

    def send(self, rig: _Rig, i: int, n: int | None = None) -> None:
        payload = encode_batch(_batch(rig, self.batch if n is None else n, self.rate_hz, seed=i))
        rig.sent_at = time.perf_counter()  # before the put: the interrupt may be stamped before put() returns
        rig.seq += 1
        self.pubs[i].put(payload)

    def wait_empty(self, dsp: Child) -> float:
        """Until every rig's board has flagged empty; returns the deadline the history fill counts from."""
        perf = time.perf_counter
        deadline = perf() + 120.0
        while any(r.empty_for < 0 for r in self.rigs):
            if perf() > deadline or not dsp.alive():
                raise BenchError(f"not every rig's board flagged empty; {dsp.describe_failure()}")
            self.take(perf() + 0.2)
        return deadline

    def fill(self, total: int, fft_width: int, deadline: float) -> None:
        """Fill each rig's history once (closed loop), so every timed step is a full one."""
        fill = max(self.batch, 30)  # the history is filled with batches of at least 30 samples (l = 1 would take N round trips)
        for i, rig in enumerate(self.rigs[:total]):
            for _ in range(math.ceil(fft_width / fill)):
                while rig.empty_for < rig.seq:
                    if time.perf_counter() > deadline + 300.0:
                        raise BenchError("history fill stalled")
                    self.take(time.perf_counter() + 0.05)
                self.send(rig, i, fill)

    def rung(self, k: int, seconds: float, dsp: Child) -> tuple[float, float, list[float], int, int]:
        """``k`` rigs driven for ``seconds``: the DSP's CPU seconds, the wall seconds,
        the turnarounds, how many were over the period and how many batches were due
        while their block was still full."""
        perf, period = time.perf_counter, self.period
        active = self.rigs[:k]
        for j, rig in enumerate(active):
            rig.turnaround.clear()
            rig.compute.clear()
            rig.full_when_due = 0
            rig.next_due = perf() + period * j / k  # spread the rigs over the period
        cpu0, t0 = _cpu_s(dsp.popen.pid), perf()
        end = t0 + seconds
        while perf() < end:
            now = perf()
            for i, rig in enumerate(active):
                if now >= rig.next_due:
                    if rig.empty_for >= rig.seq and rig.sent_at is None:
                        self.send(rig, i)
                    else:
                        rig.full_when_due += 1  # the board is behind: this rig's deadline passed
                    rig.next_due += period
            self.take(min(r.next_due for r in active))
        self.take(perf() + 2 * period)
        cpu = _cpu_s(dsp.popen.pid) - cpu0
        wall = perf() - t0
        samples = [t for r in active for t in r.turnaround]
        return cpu, wall, samples, sum(1 for t in samples if t > period), sum(r.full_when_due for r in active)

    def close(self) -> None:
        for pub in self.pubs:
            pub.undeclare()
