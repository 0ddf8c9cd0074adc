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
as such. Nothing here asserts a time.
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

from protocol.batch_codec import encode_batch
from protocol.keys import Keys
from protocol.messages import BlockFlag, Interrupt, decode
from workbench.bench.pingers import sample_batch, zenoh_session
from workbench.bench.procs import BenchError, Child, clean_env, free_tcp_port, private_rig_id
from workbench.bench.stats import summarize

RATE_HZ = 200.0
FFT_WIDTH = 2048
BATCH = 30  #: DspSettings' default batch size: a 150 ms batch period at 200 Hz


@dataclass
class _Rig:
    keys: Keys
    seq: int = 0
    empty_for: int = -1  #: next_batch_seq of the latest empty flag
    sent_at: float | None = None
    next_due: float = 0.0
    turnaround: list[float] = field(default_factory=list)
    full_when_due: int = 0


def _cpu_s(pid: int) -> float:
    """utime + stime of a process (Linux /proc)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        parts = f.read().rsplit(")", 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf("SC_CLK_TCK")


def bench_dsp_rigs(ctx: Any, result: dict[str, Any]) -> None:
    """The rungs above; results per rung and the largest rung served."""
    rungs = (1, 4, 16) if ctx.quick else (1, 4, 16, 32, 64)
    seconds = 2.0 if ctx.quick else 6.0
    total = max(rungs)
    period = BATCH / RATE_HZ
    base = private_rig_id("rigs")
    ids = [f"{base}-{i}" for i in range(total)]
    port = free_tcp_port()
    result["config"] = {
        "rigs_served_by_the_process": total,
        "rungs": list(rungs),
        "seconds_per_rung": seconds,
        "fft_width": FFT_WIDTH,
        "batch": BATCH,
        "rate_hz": RATE_HZ,
        "budget_ms": period * 1e3,
    }
    m = result["measurements"]
    with ExitStack() as stack:
        env = clean_env(
            {
                "RALF_RIG_ID": ids[0],
                "RALF_SERVE_RIGS": ",".join(ids[1:]),
                "RALF_ZENOH_MODE": "peer",
                "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}",
                "RALF_EMULATED_LATENCY_S": "0",
                "RALF_FFT_WIDTH": str(FFT_WIDTH),
                "RALF_BATCH_SIZE": str(BATCH),
                "RALF_LOG_LEVEL": "WARNING",
            }
        )
        dsp = stack.enter_context(Child([sys.executable, "-m", "dsp_service"], env=env, name="dsp-rigs", log_dir=ctx.log_dir))
        session = zenoh_session(connect=[f"tcp/127.0.0.1:{port}"])
        stack.callback(session.close)
        events: queue.SimpleQueue[tuple[int, str, bytes, float]] = queue.SimpleQueue()
        rigs = [_Rig(Keys(rig)) for rig in ids]
        perf = time.perf_counter
        pubs = []
        for i, rig in enumerate(rigs):
            for kind, key in (("flag", rig.keys.flag), ("irq", rig.keys.interrupt)):

                def on_sample(sample: Any, i: int = i, kind: str = kind) -> None:
                    events.put((i, kind, sample.payload.to_bytes(), perf()))

                sub = session.declare_subscriber(key, on_sample)
                stack.callback(sub.undeclare)
            pubs.append(session.declare_publisher(rig.keys.batch))

        def take(until: float) -> None:
            """Handle events until ``until`` (perf time)."""
            while True:
                remaining = until - perf()
                if remaining <= 0:
                    return
                try:
                    i, kind, payload, arrived = events.get(timeout=remaining)
                except queue.Empty:
                    return
                rig = rigs[i]
                if kind == "flag":
                    flag = decode(BlockFlag, payload)
                    if flag.state == "empty":
                        rig.empty_for = max(rig.empty_for, flag.next_batch_seq)
                else:
                    irq = decode(Interrupt, payload)
                    if rig.sent_at is not None and irq.batch_seq == rig.seq - 1:
                        rig.turnaround.append(arrived - rig.sent_at)
                        rig.sent_at = None

        def send(rig: _Rig, i: int) -> None:
            payload = encode_batch(sample_batch(rig.seq, BATCH, RATE_HZ, seed=i))
            rig.sent_at = perf()  # before the put: the interrupt may be stamped before put() returns
            rig.seq += 1
            pubs[i].put(payload)

        ctx.say(f"  one DSP process serving {total} rigs; waiting for their empty flags")
        deadline = perf() + 120.0
        while any(r.empty_for < 0 for r in rigs):
            if perf() > deadline or not dsp.alive():
                raise BenchError(f"not every rig's board flagged empty; {dsp.describe_failure()}")
            take(perf() + 0.2)
        # fill each rig's history once (closed loop), so every timed step is a full one
        for i, rig in enumerate(rigs[: max(rungs)]):
            for _ in range(math.ceil(FFT_WIDTH / BATCH)):
                while rig.empty_for < rig.seq:
                    if perf() > deadline + 300.0:
                        raise BenchError("history fill stalled")
                    take(perf() + 0.05)
                send(rig, i)
        take(perf() + 0.5)
        served = 0
        per_batch = (math.nan, 0)
        for k in rungs:
            active = rigs[:k]
            for j, rig in enumerate(active):
                rig.turnaround.clear()
                rig.full_when_due = 0
                rig.next_due = perf() + period * j / k  # spread the rigs over the period
            cpu0, t0 = _cpu_s(dsp.popen.pid), perf()
            end = t0 + seconds
            while perf() < end:
                now = perf()
                for i, rig in enumerate(active):
                    if now >= rig.next_due:
                        if rig.empty_for >= rig.seq and rig.sent_at is None:
                            send(rig, i)
                        else:
                            rig.full_when_due += 1  # the board is behind: this rig's deadline passed
                        rig.next_due += period
                take(min(r.next_due for r in active))
            take(perf() + 2 * period)
            cpu = _cpu_s(dsp.popen.pid) - cpu0
            wall = perf() - t0
            samples = [t for r in active for t in r.turnaround]
            late = sum(1 for t in samples if t > period)
            behind = sum(r.full_when_due for r in active)
            batches = len(samples)
            if not samples:
                raise BenchError(f"no interrupt in the rung of {k} rigs; {dsp.describe_failure()}")
            summary = summarize(samples)
            entry: dict[str, Any] = {
                "kind": "latency",
                **summary,
                "floor": "budget (batch period)",
                "floor_value_us": period * 1e6,
                "ratio": {"p99": float(summary["p99_us"]) / (period * 1e6)},
                "late": late,
                "behind": behind,
                "dsp_cpu_fraction": cpu / wall,
                "dsp_cpu_per_batch_us": cpu / batches * 1e6,
            }
            m[f"{k} rigs: batch_to_interrupt"] = entry
            ctx.say(
                f"  {k:>3} rigs: {batches} batches, p99 {entry['p99_us'] / 1e3:.2f} ms (budget {period * 1e3:.0f} ms), "
                f"late {late}, behind {behind}, DSP CPU {cpu / wall:.0%} of one core"
            )
            if late == 0 and behind == 0:
                served = k
            per_batch = (cpu / batches, k)
        m["rigs_per_core_by_cpu"] = {
            "kind": "scalar",
            "value": round(period / per_batch[0], 1),
            "unit": "rigs",
            "note": f"extrapolated: batch period / DSP CPU time per batch at {per_batch[1]} rigs",
        }
        m["rigs_served"] = {
            "kind": "scalar",
            "value": served,
            "unit": "rigs",
            "note": f"largest rung with no late or missed interrupt (rungs {list(rungs)}, N = {FFT_WIDTH}, 200 Hz, l = {BATCH})",
        }
        for pub in pubs:
            pub.undeclare()
