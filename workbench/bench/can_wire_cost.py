"""Bench item ``can-wire``: what the simulated CAN wire (:mod:`workbench.cosim_wire`) costs the
co-simulation. The same default loop co-simulated three times in this process, back to back:
without the wire (the direct wire), with it at 1 Mbit/s, and with it beside the 50 % restbus of
``docs/results/can-bus-load.md``; per run the process CPU time, and the wire's own cost per
frame on the wire (CPU time over the direct run's, divided by the frames the wire carried).
Ratios are printed; nothing is asserted on a time."""

from __future__ import annotations

import time
from typing import Any

from workbench.bench.entries import BenchContext, requires, scalar


def _cpu_run(sim_s: float, common: dict[str, Any] | None) -> tuple[float, Any]:
    from workbench.cosim import run_cosim

    cpu = time.process_time()
    run = run_cosim(controller={"duration_s": sim_s}, common=common)
    return time.process_time() - cpu, run


def bench_can_wire(ctx: BenchContext, result: dict[str, Any]) -> None:
    requires("workbench.cosim_wire")
    from workbench.can_load_table import level_path

    sim_s = 5.0 if ctx.quick else 20.0
    ctx.say(f"  co-simulation of the default loop, {sim_s:.0f} s simulated: no wire, wire at 1 Mbit/s, wire with the 50 % restbus")
    _cpu_run(1.0, None)  # warm-up: imports, compiled kernels
    cases = {
        "no wire": None,
        "wire 1 Mbit/s": {"can_bitrate": 1_000_000},
        "wire 1 Mbit/s + 50 % restbus": {"can_bitrate": 1_000_000, "can_restbus": str(level_path(50, 1_000_000))},
    }
    if not level_path(50, 1_000_000).is_file():  # the examples come with a source checkout
        ctx.say(f"  no {level_path(50, 1_000_000).name} here (run from a source checkout for the restbus case)")
        del cases["wire 1 Mbit/s + 50 % restbus"]
    m = result["measurements"]
    direct_cpu: float | None = None
    for name, common in cases.items():
        cpu, run = _cpu_run(sim_s, common)
        if run.result.error:
            result["errors"].append(f"{name}: run ended with {run.result.error}")
        ticks = max(run.result.ticks, 1)
        if direct_cpu is None:
            direct_cpu = cpu
            m[f"{name}: cpu per tick"] = scalar(cpu / ticks * 1e6, "us")
            continue
        m[f"{name}: cpu per tick"] = scalar(cpu / ticks * 1e6, "us", "no wire", direct_cpu / ticks * 1e6)
        bus = run.can_bus or {}
        frames = float(bus.get("frames_per_s", 0.0)) * float(bus.get("span_s", 0.0))
        m[f"{name}: wire cost per frame"] = scalar(
            (cpu - direct_cpu) / frames * 1e6 if frames > 0 else None, "us", frames=round(frames), note="CPU time over the direct run's / frames on the wire"
        )
    result["config"] = {"sim_s": sim_s, "controller": "default loop (default settings)", "cases": list(cases)}
    result["notes"].append("one process, back to back: the host's load at the time weighs on all three alike")
