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
from collections.abc import Callable
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
class TickAction:
    """The controller's injection stage with one action added: ``action`` runs
    in the loop's thread before tick ``tick``, once (lockstep: the rig waits
    for it, so what it sends is in from that tick on, however loaded the host).
    The fault scenario's own loop stalls still apply."""

    base: Any
    tick: int
    action: Callable[[], None]
    done: bool = False

    @property
    def stall_at_tick(self) -> int:
        return self.tick if not self.done else (self.base.stall_at_tick if self.base.stall_at_tick is not None else -1)

    def stall_now(self, tick: int) -> float:
        if not self.done and tick >= self.tick:
            self.done = True
            self.action()
        return float(self.base.stall_now(tick))

    def __getattr__(self, name: str) -> Any:  # the base's other fields (at_ticks)
        if name == "base":  # not yet set (a copy or unpickling under way): no recursion
            raise AttributeError(name)
        return getattr(self.base, name)


@dataclass
class InProcessRun:
    """What a one-process run leaves behind."""

    result: RunResult
    controller: ControllerService
    dsp: DspService
    wall_time_s: float
    health: dict[str, Health]
    """The last health message of each service (their final one, sent on stop)."""
    can_bus: dict[str, Any] | None = None
    """The simulated wire's figures (``can_bitrate`` set), as :attr:`workbench.cosim.CosimRun.can_bus`."""


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
    at_tick: tuple[int, Callable[[], None]] | None = None,
    stop: threading.Event | None = None,
) -> InProcessRun:
    """Run one rig to the controller's end (``duration_s`` or ``repeats``
    must be set) in lockstep unless ``common`` says otherwise.

    ``at_tick = (n, action)``: ``action()`` runs in the controller's loop
    before tick ``n`` (:class:`TickAction`): a command or an attack that
    lands at a known tick, not at a wall-clock moment. ``stop``: an event
    that ends the run early when set (its services stop as on SIGTERM)."""
    channel = str((common or {}).get("can_channel") or f"ralf-{uuid.uuid4().hex[:8]}")  # a channel the caller chose: its own bus can join
    base = {"clock": "lockstep", "can_interface": "virtual", "can_channel": channel, "rig_id": f"local-{channel[5:]}", **(common or {})}
    cs = ControllerSettings(**{**base, **(controller or {})})
    if cs.duration_s is None and cs.repeats == 0:
        raise ValueError("a one-process run needs controller duration_s or repeats")
    ps = PlantSettings(**{**base, **(plant or {})})
    ds = DspSettings(**{**base, **(dsp or {})})
    own_session = session is None
    sess = session or _local_session()
    stop = stop if stop is not None else threading.Event()
    health: dict[str, Health] = {}

    def keep_health(sample: zenoh.Sample) -> None:
        msg = decode(Health, sample.payload.to_bytes())
        health[msg.service] = msg

    # Everything opened is closed again, also when a service refuses its settings before the run
    # (a zenoh session or subscriber left open keeps its threads, and this process, alive).
    health_sub: Any = None
    wire: Any = None
    plant_bus: can.BusABC | None = None
    ctrl_bus: can.BusABC | None = None
    dsp_service: DspService | None = None
    ctrl: ControllerService | None = None
    threads: list[threading.Thread] = []
    started = time.monotonic()
    try:
        health_sub = sess.declare_subscriber(Keys(cs.rig_id).health_all, keep_health)
        wire = _wire(cs, ps)
        plant_bus = wire.plant_bus() if wire is not None else can.Bus(interface="virtual", channel=channel)
        ctrl_bus = wire.controller_bus() if wire is not None else can.Bus(interface="virtual", channel=channel)
        dsp_service = DspService(ds, sess)
        threads = [
            threading.Thread(target=serve_plant, args=(ps, sess, plant_bus, stop), kwargs={"owns_process": False}, name="plant", daemon=True),
            threading.Thread(target=dsp_service.run, args=(stop,), name="dsp", daemon=True),
        ]
        ctrl = ControllerService(cs, sess, PlantLink(ctrl_bus, cs.node_id), keep_record=True)  # callers read controller.record
        ctrl.owns_process = False  # the services share this process: real-time measures stay on each loop's thread
        if at_tick is not None:
            ctrl.injection = TickAction(ctrl.injection, *at_tick)  # type: ignore[assignment]
        started = time.monotonic()
        for t in threads:
            t.start()
        result = ctrl.run(stop)
    finally:
        if wire is not None:
            wire.shutdown()  # the end's frames (valves to zero, NMT) reach the plant before it stops
        stop.set()
        for t in threads:
            if t.ident is not None:
                t.join(timeout=10)
        if ctrl is not None:
            ctrl.close()
        if dsp_service is not None:
            dsp_service.close()
        time.sleep(0.05)
        if health_sub is not None:
            health_sub.undeclare()
        for bus in (plant_bus, ctrl_bus):
            if bus is not None:
                bus.shutdown()
        if own_session:
            sess.close()
    ctrl.finish(result)  # the run record, as the controller service writes it at its end
    return InProcessRun(
        result=result,
        controller=ctrl,
        dsp=dsp_service,
        wall_time_s=time.monotonic() - started,
        health=dict(health),
        can_bus=wire.summary() if wire is not None else None,
    )


def _wire(cs: ControllerSettings, ps: PlantSettings) -> Any:
    """The simulated CAN wire between the two threads (``can_bitrate`` set; :mod:`workbench.lockstep_wire`), else None."""
    if not cs.can_bitrate:
        return None
    if cs.clock != "lockstep":
        raise ValueError(f"RALF_CAN_BITRATE={cs.can_bitrate}: the simulated CAN wire needs simulated time (clock lockstep or the co-simulation)")
    from workbench.cosim_wire import load_restbus
    from workbench.lockstep_wire import LockstepWire

    restbus = load_restbus(cs.can_restbus, cs.can_bitrate, ps.node_id) if cs.can_restbus else None
    return LockstepWire(node_id=ps.node_id, bitrate=cs.can_bitrate, sample_period_s=cs.sample_period_s, restbus=restbus)
