"""Measure the campaign engine on this machine: ``ralf-hil measure campaign [--blocks 2] [--runs 6] [--duration 10] [--json out.json]``.

* **throughput**: the same sweep of ``--runs`` lockstep runs (``--duration``
  simulated seconds each) on a local cluster of one worker and of two
  workers, in interleaved blocks (1, 2, 1, 2, ...) so both see the same
  machine state; runs per hour, simulated seconds per wall second, and the
  two-worker/one-worker ratio per block;
* **worker start-up**: wall time from asking for the local cluster until
  every worker joined (each block's clusters);
* **scheduling per task**: the client's round trip of a no-op task minus its
  run time on the worker, one task at a time, and the wall time per task of
  a burst of no-op tasks;
* **result transfer**: the extra round trip of a task returning 1 and 8 MB.

The machine's load average before and after is printed next to the numbers:
on a shared host they are what they are, and only the ratios measured in the
same session compare.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from workbench.campaign.engine import Engine
from workbench.campaign.spec import SweepSpec
from workbench.campaign.sweep import run_sweep


def noop(x: int) -> int:
    """A task that does nothing."""
    return x


def payload(megabytes: int) -> np.ndarray:
    """A task returning ``megabytes`` MB."""
    return np.ones(megabytes * 131072, dtype=np.float64)


def _spec(runs: int, duration_s: float, block: int) -> SweepSpec:
    return SweepSpec(
        name=f"measure-{block}",
        base={
            "controller.duration_s": duration_s,
            "batch_size": 20,
            "controller.tf_download_samples": 0,
            "controller.oatf_mode": "adaptive",
            "dsp.fft_width": 1024,
            "dsp.alpha": 0.05,
        },
        seeds=[1000 * block + i for i in range(runs)],
    )


def overheads(engine: Engine, n: int = 40) -> dict[str, float]:
    """Per-task scheduling and result-transfer costs of ``engine`` (see the module doc)."""
    single = []
    for i in range(n // 2):
        out = engine.map(noop, [i], keys=[f"noop-{i}"], show_progress=False)[0]
        single.append(out.round_trip_s - out.run_s)
    started = time.perf_counter()
    engine.map(noop, list(range(n * 5)), show_progress=False, description="burst")
    burst = (time.perf_counter() - started) / (n * 5)
    transfer: dict[str, float] = {}
    for mb in (1, 8):
        rt = []
        for k in range(3):
            got = engine.map(payload, [mb], keys=[f"payload-{mb}-{k}"], show_progress=False)[0]
            rt.append(got.round_trip_s - got.run_s)
        transfer[f"result_{mb}mb_extra_s"] = statistics.median(rt) - statistics.median(single)
    return {"task_round_trip_overhead_s": statistics.median(single), "burst_wall_per_task_s": burst, **transfer}


def measure(blocks: int, runs: int, duration_s: float) -> dict[str, Any]:
    result: dict[str, Any] = {
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(), "load_before": os.getloadavg()},
        "runs_per_sweep": runs,
        "run_duration_s": duration_s,
        "blocks": [],
    }
    with tempfile.TemporaryDirectory(prefix="ralf-measure-") as tmp:
        for b in range(blocks):
            block: dict[str, Any] = {}
            for workers in (1, 2):
                engine = Engine.local(workers)
                try:
                    started = time.perf_counter()
                    res = run_sweep(_spec(runs, duration_s, b), Path(tmp) / f"b{b}w{workers}", engine, resume=False, show_progress=False)
                    wall = time.perf_counter() - started
                    ok = [o for o in res.outcomes if o.ok]
                    entry: dict[str, Any] = {
                        "startup_s": engine.started_s,
                        "wall_s": wall,
                        "runs": len(res.outcomes),
                        "failed": res.failed,
                        "runs_per_hour": 3600.0 * len(ok) / wall,
                        "sim_s_per_wall_s": len(ok) * duration_s / wall,
                        "mean_run_s": statistics.mean(o.run_s for o in ok) if ok else float("nan"),
                        "mean_queue_and_overhead_s": statistics.mean(o.round_trip_s - o.run_s for o in ok) if ok else float("nan"),
                        "load": os.getloadavg()[0],
                    }
                    if b == 0:
                        entry["overheads"] = overheads(engine)
                finally:
                    engine.close()
                block[f"workers_{workers}"] = entry
            block["speedup_2_over_1"] = block["workers_2"]["runs_per_hour"] / block["workers_1"]["runs_per_hour"]
            result["blocks"].append(block)
    result["machine"]["load_after"] = os.getloadavg()
    result["speedup_2_over_1_median"] = statistics.median(b["speedup_2_over_1"] for b in result["blocks"])
    return result


def main(args: argparse.Namespace) -> int:
    res = measure(args.blocks, args.runs, args.duration)
    text = json.dumps(res, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m workbench.campaign.measure", "ralf-hil measure campaign")
