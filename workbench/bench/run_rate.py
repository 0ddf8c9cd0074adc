"""``ralf-hil bench --only runs``: co-simulated runs per second, start-up included.

The same run (the default loop, ``RUN_S`` simulated seconds, one seed per
run) as many times as fit, one after another in this process (one core), and
the same runs as tasks on the campaign engine's local Dask cluster
(:class:`workbench.campaign.engine.Engine`, one single-threaded worker per
core). Every run builds its settings, plant, controller and DSP and writes
nothing; its wall time counts from ``run_cosim``'s call to its return. The
cluster's own start-up is measured apart (it is paid once per campaign).

Runs per second on one core against its floor, the runs per second the
runs' own ``wall_time_s`` would allow (from the controller's construction to
the plant's close; the settings, the plant model and the DSP core are built
before it): what building a run costs a short one.
"""

from __future__ import annotations

import os
import time
from typing import Any

from workbench.bench.entries import BenchContext, requires, scalar

__all__ = ["RUN_S", "bench_runs", "one_run"]

RUN_S = 30.0
"""Simulated seconds of each run."""


def one_run(seed: int, run_s: float = RUN_S) -> dict[str, float]:
    """One co-simulated run of ``run_s`` s (a campaign task: module-level, picklable
    arguments); its wall time from the call to the return, and the loop's own."""
    from workbench.cosim import run_cosim

    started = time.perf_counter()
    run = run_cosim(controller={"duration_s": run_s}, plant={"seed": seed})
    return {"wall_s": time.perf_counter() - started, "loop_s": run.wall_time_s, "ticks": float(run.result.ticks), "failed": float(bool(run.result.error))}


def bench_runs(ctx: BenchContext, result: dict[str, Any]) -> None:
    """Runs per second on one core and on the local cluster."""
    requires("workbench.cosim")
    n = 4 if ctx.quick else 12
    run_s = 5.0 if ctx.quick else RUN_S
    m = result["measurements"]
    result["config"] = {"runs": n, "run_s": run_s, "load_before": os.getloadavg(), "cpus": os.cpu_count()}
    one_run(0, 1.0)  # imports and compiled kernels, as a worker's first task would pay them
    ctx.say(f"  {n} runs of {run_s:g} s, one after another in this process")
    started = time.perf_counter()
    single = [one_run(1000 + i, run_s) for i in range(n)]
    wall = time.perf_counter() - started
    loop_s = sum(r["loop_s"] for r in single)
    failed = int(sum(r["failed"] for r in single))
    m["runs per second, one core"] = scalar(
        n / wall,
        "runs/s",
        "the runs' own wall_time_s (controller built to plant closed: settings, model, DSP build excluded)",
        n / loop_s,
        run_s=run_s,
        mean_run_wall_s=wall / n,
        note="each run's settings, models, controller and DSP built and freed in the run's time",
    )
    if failed:
        result["errors"].append(f"{failed} of {n} runs on one core ended with an error")
    try:
        requires("distributed")
    except Exception as exc:  # noqa: BLE001 - Skip: the cluster figure is left out, the one-core one kept
        result["skipped"].append(f"local cluster: {exc}")
        return
    from workbench.campaign.engine import Engine

    workers = os.cpu_count() or 1
    ctx.say(f"  the same runs on a local Dask cluster of {workers} worker(s)")
    asked = time.perf_counter()
    with Engine.local(workers) as engine:
        up_s = time.perf_counter() - asked
        engine.map(_one_run_of, [(i, 1.0) for i in range(workers)], keys=[f"warm-{i}" for i in range(workers)], show_progress=False)  # each worker's first task
        started = time.perf_counter()
        outcomes = engine.map(_one_run_of, [(2000 + i, run_s) for i in range(n)], show_progress=False, description="runs")
        wall = time.perf_counter() - started
    bad = [o for o in outcomes if not o.ok or o.value is None or o.value["failed"]]
    if bad:
        result["errors"].append(f"{len(bad)} of {n} runs on the cluster failed: {bad[0].error or 'run ended with an error'}")
    m["runs per second, local cluster"] = scalar(
        n / wall, "runs/s", "one core", n / (sum(r["wall_s"] for r in single) or float("nan")), workers=workers, cluster_start_s=up_s
    )
    result["config"]["load_after"] = os.getloadavg()


def _one_run_of(args: tuple[int, float]) -> dict[str, float]:
    return one_run(*args)
