"""Recording a co-simulation (``--clock cosim``): the same MCAP file as a
three-process run, fed from inside the one thread.

A co-simulation has no bus and no zenoh network to listen on, so the tap
sits where they would be: :class:`RecordingWire` wraps the CAN wire between
the controller's link and the plant's node (every frame, both ways), and
:class:`RecordingDspPort` wraps the controller's DSP port (batches, the
DSP's configuration, status, TF downloads one way; flags, interrupts,
configuration acknowledgements and liveliness the other). The plant's truth,
channel truth (with channel faults) and events come through the plant
application's own publish hooks. Every
payload is recorded as it travelled: the encoded CAN frame, the JSON or
binary zenoh payload, on the key it would have had in ``ralf/<rig-id>/``.

Time: a co-simulation runs faster than the clock on the wall, so each
record's log time is the run's start (wall clock) plus its *simulated* time;
the file then reads like a real-time run of the same rig, and the
``ralf.run`` metadata says so (``clock: cosim``, ``log_time: start +
simulated time``). Recording changes nothing in the run: the wrappers only
read (tested: the same run record with and without).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import can

from protocol.keys import Keys
from protocol.messages import ChannelTruth, GroundTruth, Health, PlantEvent, encode
from service_kit.encodings import BATCH, JSON, TF
from workbench.recording.recorder import Recorder
from workbench.recording.schemas import TO_CONTROLLER, TO_PLANT


class RecordingWire:
    """A CAN wire (``send``/``recv``/``shutdown``) whose frames are also recorded."""

    def __init__(self, inner: Any, recorder: Recorder, now: Callable[[], float], epoch_s: float) -> None:
        self.inner = inner
        self.recorder = recorder
        self.now = now
        self.epoch_s = epoch_s

    def _record(self, msg: can.Message, direction: str) -> None:
        sim = self.now()
        self.recorder.on_can_frame(
            msg.arbitration_id, bytes(msg.data), wall_time_s=self.epoch_s + sim, is_extended_id=msg.is_extended_id, direction=direction, sim_time_s=sim
        )

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._record(msg, TO_PLANT)
        self.inner.send(msg, timeout)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        msg = self.inner.recv(timeout)
        if msg is not None:
            self._record(msg, TO_CONTROLLER)
        return msg

    def shutdown(self) -> None:
        self.inner.shutdown()

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


_DSP_KEYS: dict[str, Callable[[Keys], str]] = {
    "flag": lambda k: k.flag,
    "interrupt": lambda k: k.interrupt,
    "config_ack": lambda k: k.dsp_config_ack,
    "command": lambda k: k.controller_command,
    "test_command": lambda k: k.controller_test_command,
}
"""The key each kind of event the DSP port hands the controller travels on."""


class RecordingDspPort:
    """A controller DSP port (:class:`controller.dsp_port.DspPort`) whose traffic is also recorded."""

    def __init__(self, inner: Any, recorder: Recorder, keys: Keys, now: Callable[[], float], epoch_s: float) -> None:
        self.inner = inner
        self.recorder = recorder
        self.keys = keys
        self.now = now
        self.epoch_s = epoch_s

    @property
    def synchronous(self) -> bool:
        return bool(getattr(self.inner, "synchronous", False))

    def _put(self, key: str, payload: bytes, encoding: str) -> None:
        self.recorder.on_message(key, payload, wall_time_s=self.epoch_s + self.now(), encoding=encoding)

    def connect(self, sink: Any, clock: Any) -> None:
        def tapped(kind: str, payload: bytes, arrival: float, *attachment: Any) -> None:
            if kind == "alive":
                self.recorder.on_liveliness(self.keys.alive("dsp"), payload == b"1", wall_time_s=self.epoch_s + self.now())
            elif kind in _DSP_KEYS:
                self._put(_DSP_KEYS[kind](self.keys), bytes(payload), str(JSON))
            sink(kind, payload, arrival, *attachment)

        self.inner.connect(tapped, clock)

    def send_batch(self, payload: bytes) -> None:
        self._put(self.keys.batch, payload, str(BATCH))
        self.inner.send_batch(payload)

    def send_config(self, payload: bytes) -> None:
        self._put(self.keys.dsp_config, payload, str(JSON))
        self.inner.send_config(payload)

    def send_status(self, payload: bytes) -> None:
        self._put(self.keys.controller_status, payload, str(JSON))
        self.inner.send_status(payload)

    def publish_tf(self, payload: bytes) -> None:
        self._put(self.keys.tf_downloads, payload, str(TF))
        self.inner.publish_tf(payload)

    def publish_param_change(self, payload: bytes) -> None:
        """A parameter change taken (controller/params.py): recorded; the co-simulation's own port has no listener."""
        self._put(self.keys.param_changes, payload, str(JSON))
        inner = getattr(self.inner, "publish_param_change", None)
        if inner is not None:
            inner(payload)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)


class CosimRecording:
    """One co-simulation's MCAP file: the recorder, its metadata and the hooks to wrap the run's parts with."""

    def __init__(
        self,
        path: str,
        rig_id: str,
        now: Callable[[], float],
        settings: dict[str, dict[str, Any]],
        *,
        can_log: str | None = None,
        extra: dict[str, Any] | None = None,
    ) -> None:
        from workbench.recording.tap import run_metadata

        rate = float(settings.get("controller", {}).get("sample_rate_hz", 200.0) or 200.0)
        node_id = int(settings.get("plant", {}).get("node_id", 1) or 1)
        self.recorder = Recorder(path, sample_rate_hz=rate, node_id=node_id, can_log=can_log)
        self.keys = Keys(rig_id)
        self.now = now
        self.epoch_s = time.time()
        for name, values in run_metadata(
            rig_id, settings, **{**(extra or {}), "clock": "cosim", "log_time": "run start (wall clock) + simulated time"}
        ).items():
            self.recorder.add_metadata(name, values)

    def wire(self, inner: Any) -> RecordingWire:
        return RecordingWire(inner, self.recorder, self.now, self.epoch_s)

    def port(self, inner: Any) -> RecordingDspPort:
        return RecordingDspPort(inner, self.recorder, self.keys, self.now, self.epoch_s)

    def truth(self, message: GroundTruth) -> None:
        self.recorder.on_message(self.keys.truth, encode(message), wall_time_s=self.epoch_s + message.sim_time_s, encoding=str(JSON))

    def channel_truth(self, message: ChannelTruth) -> None:
        self.recorder.on_message(self.keys.channel_truth, encode(message), wall_time_s=self.epoch_s + message.sim_time_s, encoding=str(JSON))

    def event(self, message: PlantEvent) -> None:
        self.recorder.on_message(self.keys.plant_events, encode(message), wall_time_s=self.epoch_s + message.sim_time_s, encoding=str(JSON))

    def plant_param_change(self, payload: bytes) -> None:
        """A change of a plant parameter taken (plant_emulator/params.py), at the SYNC it is taken before."""
        self.recorder.on_message(self.keys.plant_param_changes, payload, wall_time_s=self.epoch_s + self.now(), encoding=str(JSON))

    def bus_load(self, summary: dict[str, Any]) -> None:
        """The simulated wire's figures (``can_bitrate`` set), on ``/can/bus_load`` at the run's end."""
        from workbench.recording.schemas import CAN_BUS_LOAD_SCHEMA, CAN_BUS_LOAD_TOPIC

        self.recorder.on_record(CAN_BUS_LOAD_TOPIC, CAN_BUS_LOAD_SCHEMA, summary, wall_time_s=self.epoch_s + self.now())

    def health(self, service: str, message: Health) -> None:
        self.recorder.on_message(self.keys.health(service), encode(message), wall_time_s=self.epoch_s + self.now(), encoding=str(JSON))

    def close(self) -> Any:
        return self.recorder.close()
