"""What recording costs the loop: ``ralf-hil measure recording``.

Runs ``ralf-hil up`` in real time, alternately without and with
``--record`` (pairs, so both see the same machine state), and prints per
run the controller's ticks, overruns, deadline misses, skipped periods,
TET and SYNC-lateness percentiles, the CPU seconds of the whole rig
(launcher, tap and services: ``RUSAGE_CHILDREN``), the recorder's counters
and the host's load; then the totals per mode. Run it inside the
loopback-only namespace (``.ci/loopback-netns``); it opens udp_multicast.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import uuid
from pathlib import Path
from typing import Any


def run_once(duration_s: float, record: bool, tmp: Path) -> dict[str, Any]:
    tag = uuid.uuid4().hex[:6]
    summary_path = tmp / f"{tag}.json"
    cmd = [
        sys.executable,
        "-m",
        "workbench",
        "up",
        "--duration",
        str(duration_s),
        "--rig-id",
        f"rb-{tag}",
        "--json",
        str(summary_path),
        "--log-dir",
        str(tmp / tag),
    ]
    if record:
        cmd += ["--record", str(tmp / f"{tag}.mcap")]
    load_before = os.getloadavg()[0]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=duration_s + 120, check=False)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    s = json.loads(summary_path.read_text())
    c, h = s["controller"], s["health"]["controller"]
    lat = h["latencies"]
    return {
        "record": record,
        "ticks": c["ticks"],
        "overruns": c["overruns"],
        "deadline_misses": c["deadline_misses"],
        "periods_skipped": h["counters"].get("periods_skipped", 0),
        "tet_p50_ms": lat["tet"]["p50"] * 1e3,
        "tet_p99_ms": lat["tet"]["p99"] * 1e3,
        "lateness_p99_ms": lat["sync_jitter"]["p99"] * 1e3,
        "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
        "recording": s.get("recording"),
        "exit_codes": s["exit_codes"],
    }


def main(args: argparse.Namespace) -> int:
    cost = writer_cost()
    print(
        f"recorder: {cost['us_per_frame']:.1f} us CPU per CAN frame, {cost['us_per_batch']:.0f} us per batch of 30; "
        f"a 200 Hz rig (3 frames a tick, a batch every 30) costs it {100 * cost['core_fraction_200hz']:.1f} % of one core",
        flush=True,
    )
    if args.writer_only:
        return 0
    runs = []
    with tempfile.TemporaryDirectory(prefix="rec-bench-") as tmp:
        for pair in range(args.pairs):
            for record in (False, True) if pair % 2 == 0 else (True, False):  # ABBA: no order bias
                r = run_once(args.duration, record, Path(tmp))
                runs.append(r)
                rec = r["recording"] or {}
                print(
                    f"{'with' if record else 'without':7s} ticks {r['ticks']:5d} overruns {r['overruns']:4d} misses {r['deadline_misses']:2d} "
                    f"skipped {r['periods_skipped']:4d} TET p50/p99 {r['tet_p50_ms']:.2f}/{r['tet_p99_ms']:.2f} ms lateness p99 {r['lateness_p99_ms']:.2f} ms "
                    f"cpu {r['cpu_s']:.1f} s load {r['load_before']:.1f}->{r['load_after']:.1f}"
                    + (f" | recorded {rec.get('can_frames')} frames, {rec.get('messages')} msgs, {rec.get('dropped')} dropped" if rec else ""),
                    flush=True,
                )
    for record in (False, True):
        sel = [r for r in runs if r["record"] is record]
        ticks = sum(r["ticks"] for r in sel)
        over = sum(r["overruns"] for r in sel)
        print(
            f"{'with' if record else 'without'} --record: {len(sel)} runs, {ticks} ticks, {over} overruns ({100 * over / max(ticks, 1):.2f} %), "
            f"{sum(r['deadline_misses'] for r in sel)} deadline misses, {sum(r['periods_skipped'] for r in sel)} periods skipped, "
            f"CPU {sum(r['cpu_s'] for r in sel) / max(len(sel), 1):.1f} s per run"
        )
    if args.json:
        Path(args.json).write_text(json.dumps(runs, indent=2))
    return 0


def writer_cost(n_frames: int = 20000, n_batches: int = 200) -> dict[str, float]:
    """CPU seconds the recorder spends per CAN frame and per batch (its
    writer thread and the callers' puts, measured as this process's CPU
    time over a burst), and what a 200 Hz rig costs it per second of run."""
    import time

    import numpy as np

    from protocol.batch_codec import SampleBatch, encode_batch
    from workbench.recording.recorder import Recorder

    with tempfile.TemporaryDirectory(prefix="rec-cost-") as tmp:
        rec = Recorder(Path(tmp) / "cost.mcap", queue_limit=n_frames + n_batches + 10)
        frames = [(0x080, b"\x01"), (0x181, bytes(8)), (0x201, bytes(4))]
        t0 = time.process_time()
        for i in range(n_frames):
            cob, data = frames[i % 3]
            rec.on_can_frame(cob, data, wall_time_s=1e9 + i * 1e-3)
        rec.close()
        frame_s = (time.process_time() - t0) / n_frames
        rec = Recorder(Path(tmp) / "cost2.mcap", queue_limit=n_batches + 10)
        rng = np.random.default_rng(0)
        payloads = [
            encode_batch(
                SampleBatch(
                    seq=i,
                    first_tick=30 * i,
                    sample_rate_hz=200.0,
                    sim_time_s=0.15 * i,
                    wall_time_s=1e9,
                    inputs=rng.standard_normal((2, 30)),
                    outputs=rng.standard_normal((2, 30)),
                )
            )
            for i in range(n_batches)
        ]
        t0 = time.process_time()
        for p in payloads:
            rec.on_message("ralf/cost/dsp/batch", p, wall_time_s=1e9)
        rec.close()
        batch_s = (time.process_time() - t0) / n_batches
    per_run_s = 3 * 200 * frame_s + 200 / 30 * batch_s
    return {"us_per_frame": frame_s * 1e6, "us_per_batch": batch_s * 1e6, "core_fraction_200hz": per_run_s}


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m workbench.recording.bench", "ralf-hil measure recording")
