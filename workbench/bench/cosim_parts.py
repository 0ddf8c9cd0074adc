"""Where a co-simulated tick goes: :func:`workbench.cosim.run_cosim`'s pieces, built
the same way, with the calls the controller service makes into each part
timed by wrappers (no profiler: a profiler's per-call cost would distort a
tick made of many small calls).

Parts: the plant node (``handle`` and ``poll``, through the wire), the
wire's own work, the controller's :class:`~controller.plant_link.PlantLink`
(frame encode/decode, dispatch; the node's time subtracted), the control law
(``law.step_row``: engineering, trajectory, OATF, PI, D/A, the record row), the
DSP port and core, the DSP link, the run record, and what is left: the
controller service's own per-tick work (``controller/service.py``). The
wrappers cost ~0.3 µs per call; the parts are inclusive wall times, the
service's share the rest of the run's wall time.

``python -m workbench.bench.cosim_parts [SECONDS]`` prints the table.
"""

from __future__ import annotations

import sys
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

NODE = "plant node (handle + poll)"
WIRE = "DirectCanWire own"
LINK = "PlantLink own (RPDO encode, TPDO decode, dispatch)"
SERVICE = "ControllerService own (controller/service.py)"


def _wrap(obj: Any, name: str, key: str, acc: defaultdict[str, float]) -> None:
    fn: Callable[..., Any] = getattr(obj, name)
    clock = time.perf_counter

    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = clock()
        try:
            return fn(*args, **kwargs)
        finally:
            acc[key] += clock() - t0

    setattr(obj, name, timed)


def cosim_parts(sim_s: float = 20.0, controller: dict[str, Any] | None = None) -> dict[str, Any]:
    """One co-simulation of ``sim_s`` simulated seconds (adaptive OATF unless
    ``controller`` says otherwise), timed by part; µs per tick and share."""
    from controller.plant_link import PlantLink
    from controller.service import ControllerService
    from dsp_service.core import DspCore
    from plant_emulator.node import CanopenNode
    from plant_emulator.service import PlantApplication, node_config
    from service_kit.clock import SimulatedScheduler
    from workbench.cosim import DirectCanWire, DirectDspPort, settings_for

    cs, ps, ds = settings_for({"oatf_mode": "adaptive", **(controller or {}), "duration_s": sim_s})
    scheduler = SimulatedScheduler()
    app = PlantApplication(ps, clock=scheduler.now)
    node = CanopenNode(app, node_config(ps))
    wire = DirectCanWire(node, scheduler)
    port = DirectDspPort(DspCore(ds))
    link = PlantLink(wire, cs.node_id, clock=scheduler.now)  # type: ignore[arg-type]
    ctrl = ControllerService(cs, None, link, port=port, scheduler=scheduler, keep_record=True)  # type: ignore[arg-type,unused-ignore]
    acc: defaultdict[str, float] = defaultdict(float)
    _wrap(node, "handle", "node", acc)
    _wrap(node, "poll", "node", acc)
    _wrap(wire, "send", "wire", acc)
    _wrap(wire, "recv", "wire", acc)
    for name in ("send_outputs", "send_output_values", "send_sync", "wait_tpdo", "poll", "heartbeat_age", "take_conflicts"):
        _wrap(link, name, "link", acc)
    _wrap(ctrl.law, "step_row", "law.step_row (engineering, trajectory, OATF, PI, D/A)", acc)
    for name in ("send_batch", "send_config", "download_tf", "send_status"):
        _wrap(port, name, "DSP port and core (batch codec, identification)", acc)
    for name in ("add_sample", "take_batch", "check_deadline"):
        _wrap(ctrl.link, name, "DspLink", acc)
    _wrap(ctrl.record, "append_row", "run record append", acc)
    started, cpu = time.perf_counter(), time.process_time()
    try:
        result = ctrl.run(scheduler.stop)
    finally:
        ctrl.close()
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    ticks = max(result.ticks, 1)
    parts = {NODE: acc.pop("node"), WIRE: acc.pop("wire"), LINK: acc.pop("link")}
    parts[WIRE] -= parts[NODE]
    parts[LINK] -= parts[WIRE] + parts[NODE]
    parts.update(acc)
    parts[SERVICE] = wall - sum(parts.values())
    return {
        "ticks": result.ticks,
        "wall_us_per_tick": wall / ticks * 1e6,
        "cpu_us_per_tick": cpu / ticks * 1e6,
        "parts_us_per_tick": {k: v / ticks * 1e6 for k, v in sorted(parts.items(), key=lambda kv: -kv[1])},
        "parts_share": {k: v / wall for k, v in parts.items()},
    }


def main() -> None:
    sim_s = float(sys.argv[1]) if len(sys.argv) > 1 else 20.0
    cosim_parts(1.0)  # warm-up: imports, compiled kernels
    out = cosim_parts(sim_s)
    print(f"{out['ticks']} ticks: {out['wall_us_per_tick']:.0f} µs wall, {out['cpu_us_per_tick']:.0f} µs CPU per tick (instrumented)")
    for name, us in out["parts_us_per_tick"].items():
        print(f"  {us:7.1f} µs  {out['parts_share'][name] * 100:5.1f} %  {name}")


if __name__ == "__main__":
    main()
