"""The tap: what feeds a :class:`~workbench.recording.recorder.Recorder` from
outside the control loop.

A zenoh subscriber on ``ralf/<rig>/**`` (plus a liveliness subscriber on
``ralf/<rig>/alive/*``) and a python-can listener on the rig's bus, each
calling the recorder from its own thread (zenoh's callback thread,
python-can's notifier thread). Nothing runs in the services: recording a
run costs the loop no code path, only the host's CPU for the tap's process
(``ralf-hil up`` runs it in the launcher).

:func:`run_metadata` collects the run's metadata (settings, versions,
seed, host) for :meth:`Recorder.add_metadata`.
"""

from __future__ import annotations

import getpass
import importlib.metadata
import platform
import socket
import sys
import time
from collections.abc import Mapping
from typing import Any

import can
import zenoh

from workbench.recording.recorder import Recorder

VERSIONED_PACKAGES = ("ralf-hil", "eclipse-zenoh", "python-can", "numpy", "scipy", "pydantic", "mcap", "cantools")


class _CanTap(can.Listener):
    def __init__(self, recorder: Recorder) -> None:
        self.recorder = recorder

    def on_message_received(self, msg: can.Message) -> None:
        if msg.is_error_frame or msg.is_remote_frame:
            return
        self.recorder.on_can_frame(msg.arbitration_id, bytes(msg.data), wall_time_s=msg.timestamp or time.time(), is_extended_id=msg.is_extended_id)

    def on_error(self, exc: Exception) -> None:  # the bus went away: the recording just ends
        pass


class Tap:
    """Subscribe ``recorder`` to a rig's zenoh keys and CAN bus.

    ``session``: a zenoh session that sees the rig (the launcher's own peer,
    or one opened from settings); ``bus``: a python-can bus on the rig's
    network (the tap opens none itself, so the caller chooses the interface;
    a ``udp_multicast`` bus must not receive its own frames).
    """

    def __init__(self, recorder: Recorder, rig_id: str, *, session: zenoh.Session | None = None, bus: can.BusABC | None = None) -> None:
        self.recorder = recorder
        self.rig_id = rig_id
        self._subs: list[Any] = []
        self._notifier: can.Notifier | None = None
        if session is not None:
            root = f"ralf/{rig_id}"
            self._subs.append(session.declare_subscriber(f"{root}/**", self._on_sample))
            self._subs.append(session.liveliness().declare_subscriber(f"{root}/alive/*", self._on_alive, history=True))
        if bus is not None:
            self._notifier = can.Notifier(bus, [_CanTap(recorder)], timeout=0.1)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.PUT:
            return
        self.recorder.on_message(str(sample.key_expr), sample.payload.to_bytes(), wall_time_s=time.time(), encoding=str(sample.encoding))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        self.recorder.on_liveliness(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT, wall_time_s=time.time())

    def close(self) -> None:
        """Stop listening (the recorder stays open: close it after)."""
        if self._notifier is not None:
            self._notifier.stop(timeout=1.0)
            self._notifier = None
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # the session may already be closed
                pass
        self._subs = []


def versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0]}
    for name in VERSIONED_PACKAGES:
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def run_metadata(rig_id: str, settings: Mapping[str, Mapping[str, Any]] | None = None, **extra: Any) -> dict[str, dict[str, Any]]:
    """The metadata records of a run: ``ralf.run`` (rig id, host, versions,
    seed, start time, command line, extra facts) and ``ralf.settings.<service>``
    (each service's settings as it resolved them)."""
    seed = (settings or {}).get("plant", {}).get("seed")
    run: dict[str, Any] = {
        "rig_id": rig_id,
        "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "host": socket.gethostname(),
        "user": _user(),
        "platform": platform.platform(),
        "cpus": str(_cpus()),
        "versions": versions(),
        "seed": seed,
        "argv": sys.argv,
        **extra,
    }
    out = {"ralf.run": run}
    for service, values in (settings or {}).items():
        out[f"ralf.settings.{service}"] = dict(values)
    return out


def _user() -> str:
    try:
        return getpass.getuser()
    except Exception:
        return ""


def _cpus() -> int:
    import os

    return os.cpu_count() or 0


def service_settings(env_by_service: Mapping[str, Mapping[str, str]], timeout_s: float = 60.0) -> dict[str, dict[str, Any]]:
    """Each service's settings as it will resolve them from its environment
    (``RALF_*`` variables), for the run metadata. Resolved in a child
    process (pydantic-settings reads ``os.environ``, which this process must
    not swap under other threads); a service whose settings do not load is
    recorded with the error."""
    import json
    import subprocess

    result = subprocess.run(
        [sys.executable, "-m", "workbench.recording.tap"],
        input=json.dumps({k: dict(v) for k, v in env_by_service.items()}),
        capture_output=True,
        text=True,
        timeout=timeout_s,
        check=False,
    )
    if result.returncode != 0:
        return {service: {"error": result.stderr.strip()[-500:]} for service in env_by_service}
    return dict(json.loads(result.stdout))


def resolve_settings_here(env_by_service: Mapping[str, Mapping[str, str]]) -> dict[str, dict[str, Any]]:
    """:func:`service_settings` in this process: swaps ``os.environ``, so only
    for a process with no other threads yet (``ralf-hil record`` before its
    session opens, the child of :func:`service_settings`)."""
    import os

    from pydantic import ValidationError

    from protocol.settings import ControllerSettings, DspSettings, PlantSettings

    models = {"dsp": DspSettings, "plant": PlantSettings, "controller": ControllerSettings}
    out: dict[str, dict[str, Any]] = {}
    saved = dict(os.environ)
    try:
        for service, env in env_by_service.items():
            model = models.get(service)
            if model is None:
                continue
            os.environ.clear()
            os.environ.update(env)
            try:
                out[service] = model().model_dump(mode="json")
            except ValidationError as exc:  # the messages only: an error's input may be a secret
                out[service] = {"error": "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())}
            except Exception as exc:
                out[service] = {"error": type(exc).__name__}
    finally:
        os.environ.clear()
        os.environ.update(saved)
    return out


def _resolve_settings_main() -> None:
    """Child side of :func:`service_settings`: JSON {service: env} on stdin -> settings on stdout."""
    import json

    json.dump(resolve_settings_here(json.load(sys.stdin)), sys.stdout)


class RigRecording:
    """A running recording of a rig started by :mod:`workbench.launcher`: the
    recorder, the tap on the launcher's zenoh session and a CAN bus of its
    own on the rig's ``udp_multicast`` port. Start it before the services
    (it then holds their start-up frames and first messages); :meth:`close`
    after they stopped."""

    def __init__(self, plan: Any, path: str | None, session: zenoh.Session, *, can_log: str | None = None, mirror: Any = None, **extra: Any) -> None:
        from protocol.settings import CommonSettings

        env = {name: plan.env_for(name) for name in ("dsp", "plant", "controller")}
        settings = service_settings({name: {k: v for k, v in e.items() if k.startswith("RALF_")} for name, e in env.items()})
        rate = float(settings.get("controller", {}).get("sample_rate_hz", 200.0) or 200.0)
        node_id = int(settings.get("plant", {}).get("node_id", 1) or 1)
        self.recorder = Recorder(path, sample_rate_hz=rate, node_id=node_id, can_log=can_log, mirror=mirror)  # mirror: the live view
        for name, values in run_metadata(plan.rig_id, settings, can_port=plan.can_port, **extra).items():
            self.recorder.add_metadata(name, values)
        common = CommonSettings(can_interface=plan.common_env["RALF_CAN_INTERFACE"], can_channel=plan.common_env["RALF_CAN_CHANNEL"], can_port=plan.can_port)
        self.bus = open_tap_bus(common)
        self.tap = Tap(self.recorder, plan.rig_id, session=session, bus=self.bus)

    def close(self) -> Any:
        self.tap.close()
        self.recorder.stats.can_socket_drops = int(getattr(self.bus, "kernel_drops", 0))
        self.bus.shutdown()
        return self.recorder.close()


def open_tap_bus(settings: Any) -> can.BusABC:
    """A bus to listen on (``udp_multicast`` without its own frames: it sends none)."""
    from service_kit.transport import open_can_bus

    kwargs: dict[str, Any] = {"receive_own_messages": False} if settings.can_interface in ("udp_multicast", "virtual") else {}
    bus = open_can_bus(settings, **kwargs)
    _widen_receive_buffer(bus)
    return bus


TAP_RCVBUF_BYTES = 4 << 20
"""The tap's socket receive buffer: a lockstep rig sends its frames back to back,
and a launcher descheduled on a loaded host must not lose them at the socket
(the kernel caps it at ``net.core.rmem_max``)."""


def _widen_receive_buffer(bus: can.BusABC) -> None:
    """Best effort: a larger ``SO_RCVBUF`` on a ``udp_multicast`` bus's socket."""
    import socket as _socket

    from service_kit.can_udp import LoopFreeUdpMulticastBus

    if isinstance(bus, LoopFreeUdpMulticastBus):
        bus.set_receive_buffer(TAP_RCVBUF_BYTES)
        return
    sock = getattr(getattr(bus, "_multicast", None), "_socket", None)
    if not isinstance(sock, _socket.socket):
        return
    try:
        sock.setsockopt(_socket.SOL_SOCKET, _socket.SO_RCVBUF, TAP_RCVBUF_BYTES)
    except OSError:
        pass


if __name__ == "__main__":
    _resolve_settings_main()
