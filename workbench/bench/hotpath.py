"""Micro-benchmark of the two hot paths of a tick, in this process, no I/O:

* controller tick: TPDO1 decode -> engineering conversion -> trajectory ->
  OATF -> PI -> D/A quantization -> RPDO1 encode -> batch append -> record row;
* plant step: SYNC frame -> one period of dynamics -> sensors -> A/D -> TPDO1 frame
  (the CANopen node's ``handle``, as the plant service runs it; and its
  ``exchange``, as the co-simulation's direct wire calls it, no python-can
  message either way);

and their parts, so each choice of means can be measured (``ralf-hil bench
--only hotpath``; ``python -m workbench.bench.hotpath`` prints the table).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import can
import numpy as np

from controller.config import build_trajectory, law_config
from controller.dsp_link import DspLink
from controller.engineering import measure
from controller.loop import ControlLaw
from controller.record import ColumnBuffer
from plant_emulator.node import CanopenNode
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
    probe = law.record_row(0, law.step(0, np.zeros(4)))
    record = ColumnBuffer({name: (np.int64 if name == "tick" else np.float64) for name in probe}, capacity=4096)
    law.pi.reset()
    ps = PlantSettings(clock="lockstep", can_interface="virtual")
    app = PlantApplication(ps)
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

    def controller_tick(i: int) -> None:
        w = can_map.decode_analog_inputs_16(tpdo.data)
        out = law.step(i, w)
        can_map.volts_to_output_frame(out.volts)
        link.add_sample(i, out.volts, out.measurement.deflection_in)
        if link.pending >= 4096:
            link._pending.clear()  # noqa: SLF001 - keep the FIFO bounded without sending
            link._pending_ticks.clear()  # noqa: SLF001
        record.append(law.record_row(i, out))

    def plant_step(i: int) -> None:
        node.handle(sync_frame(), i * ps.sample_period_s)

    def plant_step_direct(i: int) -> None:
        counter[0] = can_map.next_sync_counter(counter[0])
        node.exchange(can_map.SYNC_COB_ID, can_map.encode_sync(counter[0]), i * ps.sample_period_s)

    out = law.step(0, words)
    results = {
        "controller tick": _timed(controller_tick, n, warmup),
        "plant step (SYNC -> TPDO1)": _timed(plant_step, n, warmup),
        "  plant step, direct wire (CanopenNode.exchange)": _timed(plant_step_direct, n, warmup),
        "  tpdo decode": _timed(lambda i: can_map.decode_analog_inputs_16(tpdo.data), n, warmup),
        "  engineering (measure)": _timed(lambda i: measure(words), n, warmup),
        "  law.step (measure+trajectory+OATF+PI+D/A)": _timed(lambda i: law.step(i, words), n, warmup),
        "  PI update": _timed(lambda i: law.pi.update(out.setpoint_rad, out.measurement.phi_rad), n, warmup),
        "  rpdo encode": _timed(lambda i: can_map.volts_to_output_frame(out.volts), n, warmup),
        "  record row": _timed(lambda i: law.record_row(i, out), n, warmup),
        "  arm.advance(Ts)": _timed(lambda i: app.arm.advance(ps.sample_period_s), n, warmup),
        "  arm.sample (sensors, A/D)": _timed(lambda i: app.arm.sample(), n, warmup),
    }
    if law.oatf is not None:
        results["  OATF step"] = _timed(lambda i: law.oatf.step(out.setpoint_rad), n, warmup)  # type: ignore[union-attr]
    return results


def main() -> None:
    for name, r in bench_hotpath().items():
        ratio = r["p50_us"] / TARGET_US
        flag = "" if name.startswith(" ") else f"  ({ratio:.2f}x the {TARGET_US:.0f} µs target: {'met' if ratio <= 1.0 else 'not met'})"
        print(f"{name:48s} p50 {r['p50_us']:8.1f} µs   p99 {r['p99_us']:8.1f} µs{flag}")


if __name__ == "__main__":
    main()
