"""The direct co-simulation: plant, controller and DSP cores called in order,
each tick, in one thread (``--clock cosim``).

The same classes as the three-process rig in lockstep: the controller's
:class:`~controller.service.ControllerService` (lockstep branch), the
plant's :class:`~plant_emulator.node.CanopenNode` with its
:class:`~plant_emulator.service.PlantApplication`, the DSP's
:class:`~dsp_service.core.DspCore`. What is gone is only the transport:

* CAN: :class:`DirectCanWire` hands each frame the controller's
  :class:`~controller.plant_link.PlantLink` sends straight to the node's
  ``handle`` and keeps the node's answers for ``recv``, so every frame is
  still encoded and decoded by the CANopen codecs (12-bit words packed
  into TPDO1, D/A words into RPDO1, SYNC counters, heartbeats, SDO);
* zenoh: :class:`DirectDspPort` decodes each batch with the batch codec,
  runs the DSP core on it and hands the encoded interrupt back
  (pydantic JSON both ways); TF downloads and configuration likewise.

No threads, no queues between threads, no sockets, no zenoh. Time is a
:class:`~service_kit.clock.SimulatedScheduler` that the controller's loop
moves one sample period per tick; the plant's heartbeat runs on it. The
DSP's emulated latency is applied by the controller in simulated ticks,
exactly as in lockstep, so a co-simulation equals the three-process
lockstep run with the same settings bit for bit (tested).
"""

from __future__ import annotations

import logging
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can

from controller.plant_link import PlantLink
from controller.service import ControllerService, RunResult
from dsp_service.bank_file import load_bank, save_bank
from dsp_service.core import DspCore
from plant_emulator.canopen_node.frames import Frame
from plant_emulator.node import CanopenNode
from plant_emulator.plant_factory import build_plant_model
from plant_emulator.service import PlantApplication, build_health, node_config
from protocol.batch_codec import decode_batch
from protocol.errors import ConfigError, ProtocolError
from protocol.messages import ConfigChange, Health, decode, encode
from protocol.settings import ControllerSettings, DspSettings, PlantSettings, load_settings
from protocol.tf_codec import encode_tf
from service_kit.clock import SimulatedScheduler
from workbench.cosim_wire import TimedCanWire, load_restbus


class DirectCanWire:
    """A CAN bus with exactly two stations, the master and ``node``, in one thread.

    ``send`` delivers the frame to the node at the scheduler's time and
    keeps whatever the node answers (and whatever its timers produce) for
    ``recv``. ``recv`` with nothing waiting lets ``timeout`` of simulated
    time pass (runs the node's timers then): waiting *is* time passing.

    A standard data frame goes to the node as its COB-ID and bytes
    (:meth:`CanopenNode.exchange`: the node's ``handle`` and ``poll`` in one
    call), and the node's answers come back as its
    :class:`~plant_emulator.canopen_node.frames.Frame` objects, which read
    like :class:`can.Message` for a CANopen master: no python-can object is
    built on the plant's side, while every payload is still packed and
    unpacked by the :mod:`protocol.can_map` codecs at both ends. A master
    that has no message to hand may call :meth:`send_frame` with the COB-ID
    and payload itself."""

    def __init__(self, node: CanopenNode, scheduler: SimulatedScheduler) -> None:
        self.node = node
        self.scheduler = scheduler
        self._to_master: deque[Frame | can.Message] = deque()
        self.frames_to_node = 0
        self.frames_to_master = 0

    def _take(self, frames: list[Frame] | list[can.Message]) -> None:
        if frames:
            self._to_master.extend(frames)
            self.frames_to_master += len(frames)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.frames_to_node += 1
        now = self.scheduler.now()
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            self._take(self.node.handle(msg, now))
            self._take(self.node.poll(now))
            return
        frames = self.node.exchange(msg.arbitration_id, msg.data, now)
        if frames:
            self._to_master.extend(frames)
            self.frames_to_master += len(frames)

    def send_frame(self, arbitration_id: int, data: bytes) -> None:
        """:meth:`send` of a standard data frame given by its COB-ID and payload."""
        self.frames_to_node += 1
        frames = self.node.exchange(arbitration_id, data, self.scheduler.now())
        if frames:
            self._to_master.extend(frames)
            self.frames_to_master += len(frames)

    def recv(self, timeout: float | None = None) -> Frame | can.Message | None:
        waiting = self._to_master
        if not waiting:
            if timeout:
                self.scheduler.wait(timeout)
            frames = self.node.poll_frames(self.scheduler.now())
            if not frames:
                return None
            waiting.extend(frames)
            self.frames_to_master += len(frames)
        return waiting.popleft()

    def shutdown(self) -> None:
        self._to_master.clear()


class DirectDspPort:
    """The controller's DSP port wired straight to a :class:`DspCore`; every
    message through its codec. Implements :class:`controller.dsp_port.DspPort`."""

    synchronous = True

    def __init__(self, core: DspCore) -> None:
        self.core = core
        self._sink: Any = None
        self._clock: Any = None
        self._build_health: Any = None
        self.status: bytes | None = None
        self.board_id = f"cosim-{uuid.uuid4().hex}".encode()
        """Sent with flags and interrupts, as the DSP service sends its session id."""

    def connect(self, sink: Any, clock: Any) -> None:
        self._sink, self._clock = sink, clock
        sink("alive", b"1", clock())
        sink("flag", encode(self.core.flag("empty")), clock(), self.board_id)  # Fig. 3.5 step 1

    def send_batch(self, payload: bytes) -> None:
        try:
            batch = decode_batch(payload)
        except ProtocolError as exc:
            self.core.block.counters.decode_errors += 1
            self.core.block.last_violation = f"undecodable batch: {exc}"
            return
        admission = self.core.admit(batch)
        if not admission.accepted:
            return
        interrupt = self.core.process(batch, admission)
        self.core.release()  # the interrupt is the block's empty flag: one message, as the DSP service sends it
        self._sink("interrupt", encode(interrupt), self._clock(), self.board_id)

    def send_config(self, payload: bytes) -> None:
        try:
            self.core.apply_config(decode(ConfigChange, payload))
        except ProtocolError:
            self.core.block.counters.decode_errors += 1
        except ValueError as exc:
            self.core.block.counters.config_rejected += 1
            self.core.block.last_violation = f"config change refused: {exc}"
        self._sink("flag", encode(self.core.flag("full" if self.core.block.full else "empty")), self._clock(), self.board_id)

    def send_status(self, payload: bytes) -> None:
        self.status = payload

    def download_tf(self, timeout_s: float) -> list[bytes]:
        return [encode_tf(self.core.snapshot())]

    def publish_tf(self, payload: bytes) -> None:
        pass  # no observers in one thread (workbench.recording.cosim_tap records it when asked)

    def start_health(self, period_s: float, build: Any) -> None:
        self._build_health = build

    def health(self) -> Health | None:
        return self._build_health(0) if self._build_health is not None else None

    def close(self) -> None:
        pass


@dataclass
class CosimRun:
    """What a co-simulation leaves behind (the fields of ``workbench.composition.InProcessRun``)."""

    result: RunResult
    controller: ControllerService
    dsp: DspCore
    plant: PlantApplication
    node: CanopenNode
    wall_time_s: float
    health: dict[str, Health]
    recording: dict[str, int] | None = None
    """The recorder's counters when the run was recorded (``record=``)."""
    can_bus: dict[str, Any] | None = None
    """The simulated wire's bus load and latencies (``can_bitrate`` set: :meth:`workbench.cosim_wire.TimedCanWire.summary`)."""


def _plant_health(app: PlantApplication, node: CanopenNode) -> Health:
    return build_health(0, app, node, None)


def _dsp_health(core: DspCore) -> Health:
    counters = core.block.counters.as_dict()
    counters["interrupts"] = core.interrupt_seq
    return Health(
        seq=0,
        sim_time_s=core.last_sim_time,
        service="dsp",
        state="degraded" if core.last_batch_missed else "running",
        counters=counters,
        latencies={},
        last_miss=core.block.last_violation,
    )


def settings_for(
    controller: dict[str, Any] | None = None,
    plant: dict[str, Any] | None = None,
    dsp: dict[str, Any] | None = None,
    common: dict[str, Any] | None = None,
) -> tuple[ControllerSettings, PlantSettings, DspSettings]:
    """The three boards' settings for one co-simulated rig (lockstep semantics)."""
    base = {"rig_id": f"cosim-{uuid.uuid4().hex[:8]}", "can_interface": "virtual", "can_channel": "cosim", **(common or {}), "clock": "lockstep"}

    def load(service: str, model: type[Any], own: dict[str, Any] | None) -> Any:
        try:
            return load_settings(model, {**base, **(own or {})})
        except ConfigError as exc:
            raise ConfigError(f"{service}: {exc}") from None

    cs = load("controller", ControllerSettings, controller)
    if cs.duration_s is None and cs.repeats == 0:
        raise ValueError("a co-simulation needs controller duration_s or repeats")
    return cs, load("plant", PlantSettings, plant), load("dsp", DspSettings, dsp)


def _recording(record: str | None, can_log: str | None, extra: dict[str, Any] | None, scheduler: SimulatedScheduler, *settings: Any) -> Any:
    if not record:
        return None
    from workbench.recording.cosim_tap import CosimRecording

    resolved = {name: s.model_dump(mode="json") for name, s in zip(("controller", "plant", "dsp"), settings)}
    return CosimRecording(record, settings[0].rig_id, scheduler.now, resolved, can_log=can_log, extra=extra)


def run_cosim(
    controller: dict[str, Any] | None = None,
    plant: dict[str, Any] | None = None,
    dsp: dict[str, Any] | None = None,
    common: dict[str, Any] | None = None,
    *,
    record: str | None = None,
    can_log: str | None = None,
    record_metadata: dict[str, Any] | None = None,
    on_start: Callable[[ControllerService], None] | None = None,
) -> CosimRun:
    """Run one rig to the controller's end (``duration_s`` or ``repeats``
    must be set), every board in this thread. The plant writes its ground
    truth to its ``record`` setting, as the plant service does on stop.
    ``record`` writes the run into an MCAP file as ``ralf-hil up --record``
    does (:mod:`workbench.recording.cosim_tap`; ``can_log`` also the CAN side in
    python-can's ``.blf``/``.asc``/``.log``; ``record_metadata``: extra facts
    for its ``ralf.run`` record); the run itself is unchanged. ``on_start``
    gets the controller before its first tick (for a progress reader, which
    only reads it). The controller's ``run_record`` is written at the end,
    whole, as the controller service writes it (:meth:`ControllerService.finish`)."""
    cs, ps, ds = settings_for(controller, plant, dsp, common)
    restbus = load_restbus(cs.can_restbus, cs.can_bitrate, ps.node_id) if cs.can_restbus else None  # refused (one line) before anything runs
    model = build_plant_model(ps)  # a bad FMU is refused here (ConfigError), before anything runs
    try:
        scheduler = SimulatedScheduler()
        recording = _recording(record, can_log, record_metadata, scheduler, cs, ps, ds)
        app = PlantApplication(ps, arm=model, clock=scheduler.now)
        node = CanopenNode(app, node_config(ps))
        app.set_fault = node.set_fault
        timed = TimedCanWire(node, scheduler, app, bitrate=cs.can_bitrate, sample_period_s=cs.sample_period_s, restbus=restbus) if cs.can_bitrate else None
        wire: Any = timed if timed is not None else DirectCanWire(node, scheduler)
        core = DspCore(ds)
        load_bank(core.identifier, ds)  # as the DSP service does at its start (RALF_ARX_REGIME_BANK_FILE)
        port: Any = DirectDspPort(core)
        if recording is not None:
            app.publish_truth, app.publish_event, app.publish_channel_truth = recording.truth, recording.event, recording.channel_truth
            app.publish_param_change = recording.plant_param_change
            wire, port = recording.wire(wire), recording.port(port)
        link = PlantLink(wire, cs.node_id, clock=scheduler.now)
        started = time.monotonic()
        ctrl = ControllerService(cs, None, link, port=port, scheduler=scheduler, keep_record=True)
    except BaseException:  # the model (an FMU instance) freed on any failure before the run
        model.close()
        raise
    try:
        if on_start is not None:
            on_start(ctrl)
        result = ctrl.run(scheduler.stop)
    finally:
        if timed is not None:
            timed.shutdown()  # the end's frames (valves to zero, NMT) reach the plant
        ctrl.close()
        app.flush_side_channels()  # the last SYNC's truth, if no frame after it flushed it
        if ps.truth_record:
            app.save_truth(ps.truth_record)
        wall = time.monotonic() - started
        plant_health = _plant_health(app, node)
        app.close()  # the model freed (an FMU's instance), as the plant service does on stop
    ctrl.finish(result)  # the run record, as the controller service writes it at its end
    save_bank(core.identifier, ds)  # and at its stop
    health = {"plant": plant_health, "dsp": _dsp_health(core)}
    ctrl_health = port.health()
    if ctrl_health is not None:
        health["controller"] = ctrl_health
    recorded: dict[str, int] | None = None
    can_bus = timed.summary() if timed is not None else None
    if recording is not None and can_bus is not None:
        recording.bus_load(can_bus)
    if recording is not None:
        for service, message in health.items():
            recording.health(service, message)
        recorded = recording.close().as_dict()
    return CosimRun(result=result, controller=ctrl, dsp=core, plant=app, node=node, wall_time_s=wall, health=health, recording=recorded, can_bus=can_bus)


LOG_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


@contextmanager
def logging_to(path: Path | None) -> Iterator[None]:
    """The co-simulation's log lines (every board's, INFO and up) also into
    ``path`` while the block runs (``ralf-hil up --clock cosim --log-dir``);
    WARNING and up still reach stderr. None: nothing changes."""
    if path is None:
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    root = logging.getLogger()
    handlers: list[logging.Handler] = [logging.FileHandler(path, encoding="utf-8")]
    handlers[0].setLevel(logging.INFO)
    if not root.handlers:  # stderr as Python's last-resort handler would have it
        handlers.append(logging.StreamHandler())
        handlers[1].setLevel(logging.WARNING)
    for handler in handlers:
        handler.setFormatter(logging.Formatter(LOG_FORMAT))
        root.addHandler(handler)
    level = root.level
    root.setLevel(min(level, logging.INFO) if level else logging.INFO)
    try:
        yield
    finally:
        root.setLevel(level)
        for handler in handlers:
            root.removeHandler(handler)
            handler.close()
