"""Micro-benchmark of the two hot paths of a tick, in this process, no I/O:

* controller tick: TPDO1 decode -> engineering conversion -> trajectory ->
  OATF -> PI -> D/A quantization -> RPDO1 encode -> batch append -> record
  row appended (the per-tick forms the controller service runs: plain ints
  and floats, :meth:`ControlLaw.tick_compiled` (one compiled call,
  controller/fast_tick.py), :meth:`ColumnBuffer.append_row`);
* plant step: SYNC frame -> one period of dynamics -> sensors -> A/D -> TPDO1 frame
  (the CANopen node's ``handle``, as the plant service runs it; and its
  ``exchange``, as the co-simulation's direct wire calls it, no python-can
  message either way);

and their parts, so each choice of means can be measured (``ralf-hil bench
--only hotpath``; ``ralf-hil measure hotpath`` prints the table;
``ralf-hil measure hotpath --controller-side [SECONDS]`` the
controller's share of a co-simulated tick in CPU time, :func:`controller_side_cpu`).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from controller.config import build_trajectory, law_config
from controller.dsp_link import DspLink
from controller.engineering import measure, measure_values
from controller.loop import ROW_DEFLECTIONS, ROW_NAMES, ROW_VOLTS, ControlLaw
from controller.record import ColumnBuffer
from controller.service import RECORD_EXTRA
from plant_emulator.model import RalfArm
from plant_emulator.node import CanopenNode
from plant_emulator.plant_factory import plant_config
from plant_emulator.service import PlantApplication, node_config
from protocol import can_map
from protocol.settings import ControllerSettings, PlantSettings

TARGET_US = 100.0
"""Each hot path should take at most this long at the median (1 kHz leaves 1 ms for the whole tick)."""


def _timed(fn: Callable[[int], Any], n: int, warmup: int) -> dict[str, float]:
    for i in range(warmup):
        fn(i)
    samples = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t0 = clock()
        fn(warmup + i)
        samples[i] = clock() - t0
    us = samples / 1e3
    return {"n": n, "p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)), "max_us": float(us.max())}


def bench_hotpath(n: int = 2000, warmup: int = 200, oatf_mode: str = "adaptive") -> dict[str, dict[str, float]]:
    """p50/p99 in µs of each hot path and of its parts."""
    cs = ControllerSettings(oatf_mode=oatf_mode, duration_s=3600.0, can_interface="virtual")
    law = ControlLaw(law_config(cs), build_trajectory(cs))
    link = DspLink(sample_rate_hz=cs.sample_rate_hz, batch_size=cs.batch_size)
    names = [*ROW_NAMES, *RECORD_EXTRA, "tick"]  # the controller service's run record
    record = ColumnBuffer({name: (np.int64 if name == "tick" else np.float64) for name in names}, capacity=4096)
    ps = PlantSettings(clock="lockstep", can_interface="virtual")
    arm = RalfArm(plant_config(ps))
    app = PlantApplication(ps, arm=arm)
    node = CanopenNode(app, node_config(ps))
    ids = can_map.cob_ids(node.node_id)
    node.handle(can.Message(arbitration_id=can_map.NMT_COB_ID, data=can_map.encode_nmt(can_map.NmtCommand.START, node.node_id), is_extended_id=False), 0.0)
    counter = [0]

    def sync_frame() -> can.Message:
        counter[0] = can_map.next_sync_counter(counter[0])
        return can.Message(arbitration_id=can_map.SYNC_COB_ID, data=can_map.encode_sync(counter[0]), is_extended_id=False)

    frames = node.handle(sync_frame(), 0.0)
    tpdo = next(f for f in frames if f.arbitration_id == ids["tpdo1"])
    words = can_map.decode_analog_inputs_16(tpdo.data)
    word_list = list(can_map.decode_analog_inputs_16_values(tpdo.data))
    shift = can_map.DAC12.shift(16)

    def controller_tick(i: int) -> None:
        w0, w1, w2, w3 = can_map.decode_analog_inputs_16_values(tpdo.data)
        law.tick_compiled(i, w0, w1, w2, w3)  # as the service runs it: the law in one compiled call, RPDO1 from its codes
        row = law.row.tolist()
        c0, c1, _, _ = law.codes.tolist()
        volts = row[ROW_VOLTS : ROW_VOLTS + 2]
        can_map.encode_analog_outputs_values(c0 << shift, c1 << shift)
        link.add_sample(i, volts, row[ROW_DEFLECTIONS : ROW_DEFLECTIONS + 2])
        if link.pending >= 4096:
            link._pending.clear()  # noqa: SLF001 - keep the FIFO bounded without sending
            link._pending_ticks.clear()  # noqa: SLF001
        row.extend((law.oatf_frequency_hz, 0.0, 0.0, float("nan"), float("nan"), float("nan"), 0.0, i))
        record.append_row(row)
        if len(record) >= 4096:
            record.clear()

    def plant_step(i: int) -> None:
        node.handle(sync_frame(), i * ps.sample_period_s)

    def plant_step_direct(i: int) -> None:
        counter[0] = can_map.next_sync_counter(counter[0])
        node.exchange(can_map.SYNC_COB_ID, can_map.encode_sync(counter[0]), i * ps.sample_period_s)

    rpdo_payloads = (can_map.encode_analog_outputs_values(0x0100, -0x0100), can_map.encode_analog_outputs_values(-0x0200, 0x0080))
    setpoint = law.setpoint(0)
    phi = np.array(measure_values(word_list)[10:12])
    errors = setpoint - phi
    volts = np.array([1.25, -0.5])
    results = {
        "controller tick": _timed(controller_tick, n, warmup),
        "plant step (SYNC -> TPDO1)": _timed(plant_step, n, warmup),
        "  plant step, direct wire (CanopenNode.exchange)": _timed(plant_step_direct, n, warmup),
        "  tpdo decode": _timed(lambda i: can_map.decode_analog_inputs_16(tpdo.data), n, warmup),
        "  tpdo decode (ints)": _timed(lambda i: can_map.decode_analog_inputs_16_values(tpdo.data), n, warmup),
        "  engineering (measure, arrays)": _timed(lambda i: measure(words), n, warmup),
        "  engineering (measure_values)": _timed(lambda i: measure_values(word_list), n, warmup),
        "  law.step_row (floats: the same)": _timed(lambda i: law.step_row(i, word_list), n, warmup),
        "  law.tick_compiled (one numba call: the same)": _timed(lambda i: law.tick_compiled(i, *word_list), n, warmup),
        "  PI update (arrays)": _timed(lambda i: law.pi.update(setpoint, phi), n, warmup),
        "  PI step (one kernel call)": _timed(lambda i: law.pi.step(errors), n, warmup),
        "  rpdo encode": _timed(lambda i: can_map.volts_to_output_frame(volts), n, warmup),
        "  arm.advance(Ts)": _timed(lambda i: app.arm.advance(ps.sample_period_s), n, warmup),
        "  arm.sample (sensors, A/D)": _timed(lambda i: arm.sample(), n, warmup),
        "  arm.sample_codes (the SYNC path's A/D codes)": _timed(lambda i: app.arm.sample_codes(), n, warmup),
        "  plant RPDO1 apply, direct wire (CanopenNode.exchange)": _timed(
            lambda i: node.exchange(ids["rpdo1"], rpdo_payloads[i % 2], i * ps.sample_period_s), n, warmup
        ),
    }
    if law.oatf is not None:
        results["  OATF step (arrays)"] = _timed(lambda i: law.oatf.step(setpoint), n, warmup)  # type: ignore[union-attr]
    return results


def controller_side_cpu(sim_s: float = 10.0) -> dict[str, float]:
    """The controller's side of a co-simulated tick in CPU time: one
    :func:`workbench.cosim.run_cosim`-like run of ``sim_s`` simulated seconds
    (adaptive OATF), the thread's CPU time less the CPU time spent inside the
    wire (the plant node's ``handle`` and ``poll`` included) and the DSP port
    and core, each read with ``time.thread_time`` around those calls only
    (~4 a tick; half of each wrapper's two clock reads is taken off the
    controller's share). CPU time, not wall time: on a shared host the wall
    clock measures the other work as much as this code."""
    from collections import defaultdict

    from controller.plant_link import PlantLink
    from controller.service import ControllerService
    from dsp_service.core import DspCore
    from service_kit.clock import SimulatedScheduler
    from workbench.cosim import DirectCanWire, DirectDspPort, settings_for

    cs, ps, ds = settings_for({"oatf_mode": "adaptive", "duration_s": sim_s})
    scheduler = SimulatedScheduler()
    app = PlantApplication(ps, clock=scheduler.now)
    wire = DirectCanWire(CanopenNode(app, node_config(ps)), scheduler)
    port = DirectDspPort(DspCore(ds))
    ctrl = ControllerService(cs, None, PlantLink(wire, cs.node_id, clock=scheduler.now), port=port, scheduler=scheduler, keep_record=True)  # type: ignore[arg-type]
    spent: defaultdict[str, float] = defaultdict(float)
    calls = [0]
    clock = time.thread_time

    def timed(obj: Any, name: str, key: str) -> None:
        fn: Callable[..., Any] = getattr(obj, name)

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[key] += clock() - t0
                calls[0] += 1

        setattr(obj, name, wrapper)

    for name in ("send", "recv"):
        timed(wire, name, "plant")
    for name in ("send_batch", "send_config", "download_tf", "send_status"):
        timed(port, name, "dsp")
    t0 = clock()
    try:
        ticks = max(1, ctrl.run(scheduler.stop).ticks)
    finally:
        ctrl.close()
    total = clock() - t0
    n = 20000
    t1 = clock()
    for _ in range(n):
        clock()
    read = (clock() - t1) / n
    controller = total - spent["plant"] - spent["dsp"] - calls[0] * read
    return {
        "ticks": ticks,
        "cpu_us_per_tick": total / ticks * 1e6,
        "plant_us_per_tick": spent["plant"] / ticks * 1e6,
        "dsp_us_per_tick": spent["dsp"] / ticks * 1e6,
        "controller_us_per_tick": controller / ticks * 1e6,
    }


def main(args: argparse.Namespace) -> int:
    if args.controller_side is not None:
        controller_side_cpu(1.0)  # warm-up: imports, compiled kernels
        r = controller_side_cpu(args.controller_side)
        print(
            f"{r['ticks']:.0f} ticks, CPU per tick: {r['cpu_us_per_tick']:.1f} µs = controller {r['controller_us_per_tick']:.1f}"
            f" + plant node and wire {r['plant_us_per_tick']:.1f} + DSP port and core {r['dsp_us_per_tick']:.1f}"
        )
        return 0
    for name, r in bench_hotpath().items():
        ratio = r["p50_us"] / TARGET_US
        flag = "" if name.startswith(" ") else f"  ({ratio:.2f}x the {TARGET_US:.0f} µs target: {'met' if ratio <= 1.0 else 'not met'})"
        print(f"{name:48s} p50 {r['p50_us']:8.1f} µs   p99 {r['p99_us']:8.1f} µs{flag}")
    return 0


if __name__ == "__main__":
    from service_kit.moved import exit_moved

    exit_moved("python -m workbench.bench.hotpath", "ralf-hil measure hotpath")
