"""``ralf-hil bench --only fmu``: the FMU plant beside the built-in arm, in
the same run.

* plant step, SYNC -> TPDO1 through the CANopen node (``CanopenNode.exchange``
  with a SYNC frame: the model's step, the A/D, TPDO1's packing), the
  example FMU (examples/fmu/two_mode_plant, built with the machine's C
  compiler) against the built-in RALF arm, the two interleaved call by call
  so host load falls on both alike; the FMU's own ``doStep`` (with its
  input set and output get) from the plant's health;
* the co-simulation's real time factor (simulated s per wall s) with the
  example FMU against the 50x goal, and the built-in arm's in the same run.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from protocol import can_map
from protocol.settings import PlantSettings
from workbench.bench.entries import BenchContext, Skip, latency, requires, scalar
from workbench.bench.stats import from_latency_stats, summarize

__all__ = ["COSIM_GOAL", "bench_fmu"]

COSIM_GOAL = 50.0
"""The co-simulation with the example FMU should run at least this many times faster than real time."""


def _node(settings: PlantSettings) -> tuple[Any, Any]:
    from plant_emulator.node import CanopenNode
    from plant_emulator.plant_factory import build_plant_model
    from plant_emulator.service import PlantApplication, node_config

    app = PlantApplication(settings, arm=build_plant_model(settings))
    node = CanopenNode(app, node_config(settings))
    node.exchange(can_map.NMT_COB_ID, can_map.encode_nmt(can_map.NmtCommand.START, settings.node_id), 0.0)
    return app, node


def _plant_steps(fmu: Path, mapping: Path, n: int, warmup: int) -> tuple[dict[str, list[float]], Any]:
    base: dict[str, Any] = {"clock": "lockstep", "can_interface": "virtual", "watchdog_periods": 10000}
    rigs = {
        "built-in arm": _node(PlantSettings(**base)),
        "FMU": _node(PlantSettings(**base, model=f"fmu:{fmu}", fmu_mapping=str(mapping))),
    }
    samples: dict[str, list[float]] = {name: [] for name in rigs}
    clock = time.perf_counter
    counter = 0
    rpdo = can_map.cob_ids(1)["rpdo1"]
    try:
        for k in range(warmup + n):
            counter = can_map.next_sync_counter(counter)
            sync = can_map.encode_sync(counter)
            data, _ = can_map.volts_to_output_frame(np.array([0.05 * np.sin(0.05 * k), -0.04 * np.sin(0.07 * k)]))
            t = k / 200.0
            for name, (_, node) in rigs.items():
                t0 = clock()
                node.exchange(can_map.SYNC_COB_ID, sync, t)
                elapsed = clock() - t0
                node.exchange(rpdo, data, t)
                if k >= warmup:
                    samples[name].append(elapsed)
        fmu_app = rigs["FMU"][0]
        step_stats = fmu_app.arm.health_latencies()["fmu_step"]
    finally:
        for app, _ in rigs.values():
            app.close()
    return samples, step_stats


def _fmpy_floor(fmu: Path, mapping: Path, sim_s: float, rounds: int, m: dict[str, Any], result: dict[str, Any]) -> None:
    """The co-simulation with the FMU against FMPy's own simulation of it (:func:`workbench.bench.model_floor.fmpy_floor`)."""
    from workbench.bench.model_floor import fmpy_floor

    try:
        out = fmpy_floor(fmu, mapping, {"duration_s": sim_s}, rounds)
    except Exception as exc:  # noqa: BLE001 - reported, the item's other figures kept
        result["errors"].append(f"fmpy floor: {type(exc).__name__}: {exc}")
        return
    m["cosim with the FMU vs fmpy.simulate_fmu"] = scalar(
        out["cosim_s"],
        "s",
        "fmpy.simulate_fmu of the same FMU, same inputs and time",
        out["fmpy_s"],
        sim_s=out["sim_s"],
        rounds=out["rounds"],
        note="best of alternating rounds; both include their start-up (FMPy: extraction and instantiation)",
    )


def bench_fmu(ctx: BenchContext, result: dict[str, Any]) -> None:
    """The FMU plant's step against the built-in arm's, and the co-simulation's speed with it."""
    requires("fmpy", "yaml", "workbench.cosim")
    if shutil.which("gcc") is None:
        raise Skip("no gcc to build the example FMU")
    from plant_emulator.fmu.build import EXAMPLE_MAPPING, EXAMPLE_SOURCE, build_c_fmu
    from workbench.cosim import run_cosim

    mapping = EXAMPLE_MAPPING
    n = 500 if ctx.quick else max(ctx.iterations, 2000)
    sim_s = 10.0 if ctx.quick else 60.0
    m = result["measurements"]
    with tempfile.TemporaryDirectory(prefix="ralf-fmu-bench-") as tmp:
        fmu = build_c_fmu(EXAMPLE_SOURCE, Path(tmp) / "two_mode_plant.fmu")
        ctx.say(f"  plant step SYNC -> TPDO1, built-in arm and example FMU interleaved, {n} SYNCs each")
        samples, step_stats = _plant_steps(fmu, mapping, n, ctx.warmup)
        builtin = summarize(samples["built-in arm"])
        m["plant step, built-in arm (SYNC -> TPDO1)"] = latency(builtin)
        m["plant step, FMU (SYNC -> TPDO1)"] = latency(summarize(samples["FMU"]), "plant step, built-in arm (SYNC -> TPDO1)", builtin)
        m["  FMU doStep with input set and output get"] = latency(from_latency_stats(step_stats.model_dump()))
        plant = {"model": f"fmu:{fmu}", "fmu_mapping": str(mapping)}
        ctx.say(f"  co-simulation of the default loop, {sim_s:.0f} s simulated, example FMU and built-in arm alternately (after a 1 s warm-up each)")
        run_cosim(controller={"duration_s": 1.0}, plant=plant)
        run_cosim(controller={"duration_s": 1.0})
        speeds: dict[str, list[float]] = {"fmu": [], "builtin": []}
        for _ in range(1 if ctx.quick else 2):
            for name, p in (("fmu", plant), ("builtin", {})):
                run = run_cosim(controller={"duration_s": sim_s}, plant=p)
                if run.result.error:
                    result["errors"].append(f"cosim ({name}): run ended with {run.result.error}")
                speeds[name].append(run.result.sim_time_s / run.wall_time_s)
        ctx.say(f"  the same FMU in fmpy.simulate_fmu, {sim_s:.0f} s with the co-simulation's valve inputs, alternating with the co-simulation")
        _fmpy_floor(fmu, mapping, sim_s, 1 if ctx.quick else 2, m, result)
    fmu_x, builtin_x = float(np.median(speeds["fmu"])), float(np.median(speeds["builtin"]))
    m["cosim sim_s/wall_s, example FMU"] = scalar(fmu_x, "x", "50x goal", COSIM_GOAL, runs=speeds["fmu"])
    m["cosim sim_s/wall_s, built-in arm"] = scalar(builtin_x, "x", "the FMU's", fmu_x, runs=speeds["builtin"])
    result["config"] = {"n": n, "sim_s": sim_s, "fmu": "examples/fmu/two_mode_plant (gcc -O2)", "load_average": os.getloadavg()}
    result["notes"].append("plant steps interleaved call by call; cosim: median of alternating runs, wall time includes start-up")
