"""The three services composed in one process: the same classes as the
three-process rig, with python-can's in-process ``virtual`` bus and one
in-process zenoh session (no endpoints, no scouting) in place of the
network. For unit tests, fast experiments and the lockstep benchmark.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from dataclasses import dataclass
from typing import Any

import can
import zenoh

from controller.plant_link import PlantLink
from controller.service import ControllerService, RunResult
from dsp_service.service import DspService
from plant_emulator.service import serve as serve_plant
from protocol.keys import Keys
from protocol.messages import Health, decode
from protocol.settings import ControllerSettings, DspSettings, PlantSettings


@dataclass
class InProcessRun:
    """What a one-process run leaves behind."""

    result: RunResult
    controller: ControllerService
    dsp: DspService
    wall_time_s: float
    health: dict[str, Health]
    """The last health message of each service (their final one, sent on stop)."""


def _local_session() -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    return zenoh.open(config)


def run_in_process(
    controller: dict[str, Any] | None = None,
    plant: dict[str, Any] | None = None,
    dsp: dict[str, Any] | None = None,
    common: dict[str, Any] | None = None,
    session: zenoh.Session | None = None,
) -> InProcessRun:
    """Run one rig to the controller's end (``duration_s`` or ``repeats``
    must be set) in lockstep unless ``common`` says otherwise."""
    channel = f"ralf-{uuid.uuid4().hex[:8]}"
    base = {"clock": "lockstep", "can_interface": "virtual", "can_channel": channel, "rig_id": f"local-{channel[5:]}", **(common or {})}
    cs = ControllerSettings(**{**base, **(controller or {})})
    if cs.duration_s is None and cs.repeats == 0:
        raise ValueError("a one-process run needs controller duration_s or repeats")
    ps = PlantSettings(**{**base, **(plant or {})})
    ds = DspSettings(**{**base, **(dsp or {})})
    own_session = session is None
    sess = session or _local_session()
    stop = threading.Event()
    health: dict[str, Health] = {}

    def keep_health(sample: zenoh.Sample) -> None:
        msg = decode(Health, sample.payload.to_bytes())
        health[msg.service] = msg

    health_sub = sess.declare_subscriber(Keys(cs.rig_id).health_all, keep_health)
    plant_bus = can.Bus(interface="virtual", channel=channel)
    ctrl_bus = can.Bus(interface="virtual", channel=channel)
    dsp_service = DspService(ds, sess)
    threads = [
        threading.Thread(target=serve_plant, args=(ps, sess, plant_bus, stop), name="plant", daemon=True),
        threading.Thread(target=dsp_service.run, args=(stop,), name="dsp", daemon=True),
    ]
    ctrl = ControllerService(cs, sess, PlantLink(ctrl_bus, cs.node_id), keep_record=True)  # callers read controller.record
    started = time.monotonic()
    try:
        for t in threads:
            t.start()
        result = ctrl.run(stop)
    finally:
        stop.set()
        for t in threads:
            t.join(timeout=10)
        ctrl.close()
        dsp_service.close()
        time.sleep(0.05)
        health_sub.undeclare()
        plant_bus.shutdown()
        ctrl_bus.shutdown()
        if own_session:
            sess.close()
    return InProcessRun(result=result, controller=ctrl, dsp=dsp_service, wall_time_s=time.monotonic() - started, health=dict(health))
