"""A rig for users' own hardware-in-the-loop tests (the ``rig`` fixture of
:mod:`workbench.pytest_plugin`, usable without pytest too).

:class:`HilRig` starts the rig in the clock the test asks for:

``cosim`` (default)
    plant, controller and DSP co-simulated in one thread (:mod:`workbench.cosim`):
    fast and bit-for-bit deterministic; the run is recorded into an MCAP file
    (the :attr:`RunRecord.recording`) from which the truth, events and
    interrupts are read back. No CAN bus: the frames go straight to the node.
``lockstep`` / ``realtime``
    the three services composed in one process (:mod:`workbench.composition`):
    python-can's in-process ``virtual`` bus and an in-process zenoh session; the
    test port's truth and events and the DSP's interrupts arrive live, and the
    CAN bus (:attr:`HilRig.can`) takes the test's own frames and a ``canopen``
    master's SDO requests while the rig runs.

Handles: :attr:`HilRig.plant` (the plant's test port: scenario commands,
ground truth, events), :attr:`HilRig.dsp` (its interrupts), :attr:`HilRig.can`
(send/receive frames, a ``canopen`` ``RemoteNode`` of the plant) and the
:class:`RunRecord` a run leaves behind. Settings are checked by name before
anything starts: an unknown one is one :class:`RigSettingError`.
"""

from __future__ import annotations

import json
import math
import tempfile
import threading
import time
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any, Literal

import numpy as np

from protocol.errors import ConfigError
from protocol.messages import GroundTruth, Health, Interrupt, PlantEvent, ScenarioCommand, decode, encode
from protocol.setting_groups import Timeouts
from protocol.setting_hints import unknown_setting
from protocol.settings import CommonSettings, ControllerSettings, DspSettings, PlantSettings, load_settings, retired
from workbench.fiu import FaultInsertion
from workbench.log_counts import counting_warnings
from workbench.verdict import Verdict, judge

Clock = Literal["cosim", "lockstep", "realtime"]
CLOCKS: tuple[Clock, ...] = ("cosim", "lockstep", "realtime")
MODELS: dict[str, type[CommonSettings]] = {"controller": ControllerSettings, "plant": PlantSettings, "dsp": DspSettings, "common": CommonSettings}
PLUMBING = frozenset({"clock", "can_interface", "can_channel", "rig_id", "record", "zenoh_connect", "zenoh_listen", "zenoh_mode"})
"""Chosen by the rig itself: a test that sets one gets an error, not a silently ignored value."""


class RigSettingError(ValueError):
    """A setting the rig does not have (or one it chooses itself), a bad clock, a bad value."""


class NoCanBusError(RuntimeError):
    """The co-simulation has no CAN bus to share: ask for ``lockstep`` or ``realtime``."""


def check_settings(settings: Mapping[str, Mapping[str, Any]]) -> None:
    """Every name must be a setting of its service (``common``: of every service)."""
    for service, values in settings.items():
        if service not in MODELS:
            raise RigSettingError(f"unknown service {service!r} in the rig's settings (controller, plant, dsp, common)")
        known = MODELS[service].model_fields
        for name in values:
            if name in PLUMBING:
                raise RigSettingError(f"{service}.{name} is chosen by the rig fixture (clock by the rig_clock marker or --rig-clock)")
            if name not in known and retired(name):
                raise RigSettingError(f"{service}.{name}: {retired(name)}")
            if name not in known:
                raise RigSettingError(str(unknown_setting(name, service)))
        try:
            load_settings(MODELS[service], dict(values))
        except ConfigError as exc:
            raise RigSettingError(f"{service}: {' '.join(str(exc).split())}") from None


@dataclass
class RunRecord:
    """What a run leaves behind."""

    clock: Clock
    """The clock the run had: cosim, lockstep or realtime."""
    error: str | None
    """The controller's fault, or None when the run ended normally."""
    ticks: int
    """Control ticks run."""
    sim_time_s: float
    """Simulated time at the end of the run (s)."""
    counters: dict[str, int]
    """The controller's counters by name (each listed in docs/pytest-plugin.md)."""
    columns: dict[str, np.ndarray]
    """The controller's record: one array per column (``t_s``, ``defl1_in``, ``defl2_in``, ``phi1``, ``u1_v``, ``f_id_hz``, ...)."""
    truth: list[GroundTruth]
    """The plant's ground truth (its test port), in order."""
    events: list[PlantEvent]
    """The plant's events (hard stops, watchdog, payload), in order."""
    interrupts: list[Interrupt]
    """The DSP's interrupts (identified modes, one per batch), in order."""
    health: dict[str, Health]
    """Each service's last health message, by service name."""
    wall_time_s: float
    """Wall-clock time the run took (s)."""
    recording: Path | None = None
    """The MCAP file of a co-simulated run (open it in Foxglove with docs/foxglove-layout.json)."""
    verdict: Verdict | None = None
    """The run's verdict (:mod:`workbench.verdict`: PASS, DEGRADED, FAIL or INVALID, with what went wrong);
    the ``rig`` fixture fails a test whose run is INVALID (no tick, or a dead plant model) unless
    the test is marked ``rig_invalid_ok``."""

    def summary(self) -> str:
        """One line: what the run covered and its verdict."""
        verdict = self.verdict.line() if self.verdict is not None else "not judged"
        return f"{self.clock} run: {self.ticks} ticks ({self.sim_time_s:.2f} s simulated), {len(self.interrupts)} interrupts; {verdict}"

    @property
    def max_abs_deflection_in(self) -> float:
        """The largest measured tip deflection, either link (in)."""
        return float(np.max(np.abs(np.concatenate([self.columns["defl1_in"], self.columns["defl2_in"]])))) if self.ticks else float("nan")

    def true_first_mode_hz(self) -> np.ndarray:
        """The plant's true first modal frequency at each truth sample (Hz)."""
        return np.array([t.modal_frequencies_hz[0] for t in self.truth])


class PlantPort:
    """The plant's test port: scenario commands in, ground truth and events out."""

    def __init__(self, rig: HilRig) -> None:
        self._rig = rig
        self.pending: list[ScenarioCommand] = []
        self._sent = 0
        self.truth: list[GroundTruth] = []
        self.events: list[PlantEvent] = []

    def command(self, kind: Literal["payload", "seed", "adc_bits"], at_s: float, **value: Any) -> ScenarioCommand:
        """A scenario command, applied by the plant at simulated ``at_s`` (at once if past):
        given before the run it goes in with the run's start; during a ``lockstep``/``realtime``
        run it is published on the test port as a tester would."""
        cmd = ScenarioCommand(seq=len(self.pending) + self._sent, sim_time_s=0.0, kind=kind, at_sim_time_s=at_s, **value)
        if self._rig.started:
            self._rig._publish_scenario(cmd)
            self._sent += 1
        else:
            self.pending.append(cmd)
        return cmd

    def payload(self, attached: bool, at_s: float = 0.0) -> ScenarioCommand:
        """Attach (or release) the tip payload at simulated ``at_s``."""
        return self.command("payload", at_s, payload_attached=attached)

    def reseed(self, seed: int, at_s: float = 0.0) -> ScenarioCommand:
        return self.command("seed", at_s, seed=seed)

    def adc_bits(self, bits: Literal[12, 16, 20], at_s: float = 0.0) -> ScenarioCommand:
        return self.command("adc_bits", at_s, adc_bits=bits)


class DspPort:
    """The DSP's interrupts, as the controller received them."""

    def __init__(self) -> None:
        self.interrupts: list[Interrupt] = []


class CanPort:
    """The rig's CAN bus (``lockstep``/``realtime``): a python-can bus of the test's
    own on the rig's channel, and a ``canopen`` master for the plant's node."""

    def __init__(self, rig: HilRig) -> None:
        self._rig = rig
        self._bus: Any = None
        self._networks: list[Any] = []

    def _check(self) -> None:
        if self._rig.clock == "cosim":
            raise NoCanBusError("the co-simulation has no CAN bus; mark the test @pytest.mark.rig_clock('lockstep') to use rig.can")

    @property
    def bus(self) -> Any:
        """A python-can ``virtual`` bus on the rig's channel (sees every frame of the rig)."""
        self._check()
        if self._bus is None:
            import can

            self._bus = can.Bus(interface="virtual", channel=self._rig.can_channel)
        return self._bus

    def send(self, msg: Any) -> None:
        self.bus.send(msg)

    def recv(self, timeout: float = 1.0) -> Any:
        return self.bus.recv(timeout)

    def remote_node(self) -> Any:
        """A ``canopen.RemoteNode`` of the plant (its EDS, ``protocol/ralf_io.eds``) on a master of its own."""
        self._check()
        import canopen

        network = canopen.Network()
        network.connect(interface="virtual", channel=self._rig.can_channel)
        self._networks.append(network)
        node = canopen.RemoteNode(self._rig.node_id, str(files("protocol").joinpath("ralf_io.eds")))
        network.add_node(node)
        return node

    def close(self) -> None:
        for network in self._networks:
            network.disconnect()
        self._networks.clear()
        if self._bus is not None:
            self._bus.shutdown()
            self._bus = None


@dataclass
class HilRig:
    """One rig for one test: configure, :meth:`run` (or :meth:`start`/:meth:`wait`), read."""

    clock: Clock = "cosim"
    controller: dict[str, Any] = field(default_factory=dict)
    plant_settings: dict[str, Any] = field(default_factory=dict)
    dsp_settings: dict[str, Any] = field(default_factory=dict)
    common: dict[str, Any] = field(default_factory=dict)
    faults: str | Mapping[str, Any] | None = None
    """A link-fault scenario (:mod:`service_kit.link_faults`): a file path or its content as a mapping."""
    workdir: Path | None = None

    def __post_init__(self) -> None:
        if self.clock not in CLOCKS:
            raise RigSettingError(f"unknown rig clock {self.clock!r} (cosim, lockstep, realtime)")
        check_settings({"controller": self.controller, "plant": self.plant_settings, "dsp": self.dsp_settings, "common": self.common})
        self.rig_id = f"hil-{uuid.uuid4().hex[:8]}"
        self.can_channel = f"ralf-{self.rig_id}"
        self.node_id = int(self.common.get("node_id", self.controller.get("node_id", 1)))
        self.plant = PlantPort(self)
        self.fiu = FaultInsertion(self)
        self.dsp = DspPort()
        self.can = CanPort(self)
        self.record: RunRecord | None = None
        self._session: Any = None
        self._subs: list[Any] = []
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._stop = threading.Event()
        """Set by :meth:`close`: a ``lockstep``/``realtime`` run still going ends at once."""
        self._workdir = self.workdir or Path(tempfile.mkdtemp(prefix="ralf-hil-test-"))

    # -- running -----------------------------------------------------------------------------
    def _controller_settings(self, duration_s: float) -> dict[str, Any]:
        own = {**self.controller, "duration_s": duration_s}
        if self.faults is not None:
            own["fault_scenario"] = self.faults if isinstance(self.faults, str) else json.dumps(dict(self.faults))
        return own

    def _dsp_settings(self) -> dict[str, Any]:
        """The DSP's settings with the fault scenario (its ``dsp_delay_s`` slows the board)."""
        if self.faults is None:
            return self.dsp_settings
        return {**self.dsp_settings, "fault_scenario": self.faults if isinstance(self.faults, str) else json.dumps(dict(self.faults))}

    def set(self, service: Literal["controller", "plant", "dsp", "common"], **values: Any) -> HilRig:
        """More settings before the run (``rig.set("controller", oatf_mode="adaptive")``), checked as the markers' are."""
        if self.started:
            raise RuntimeError("settings are fixed once the rig has started")
        check_settings({service: values})
        {"controller": self.controller, "plant": self.plant_settings, "dsp": self.dsp_settings, "common": self.common}[service].update(values)
        return self

    @property
    def started(self) -> bool:
        return self._thread is not None

    def _publish_scenario(self, cmd: ScenarioCommand) -> None:
        if self._session is None:
            raise RuntimeError("the co-simulation takes scenario commands before its run only (give them before rig.run)")
        from protocol.keys import Keys

        self._session.put(Keys(self.rig_id).scenario, encode(cmd))

    def start(self, duration_s: float) -> HilRig:
        """Start a run of ``duration_s`` simulated seconds in the background (the CAN and
        test-port handles work while it runs; ``lockstep``/``realtime``: returns once the
        plant runs, its first ground truth in); :meth:`wait` for its record."""
        if self._thread is not None:
            raise RuntimeError("this rig has already run; a test gets one run per rig")
        if not duration_s > 0:
            raise RigSettingError(f"duration_s must be positive, got {duration_s}")
        if self.clock != "cosim":
            self._open_test_port()
        self._thread = threading.Thread(target=self._run_guarded, args=(duration_s,), name="hil-rig", daemon=True)
        self._thread.start()
        if self.clock != "cosim":
            self._wait_running(Timeouts.read(self.controller.get("timeouts")).startup_s + 10.0)
        return self

    def _wait_running(self, timeout_s: float) -> None:
        """Return once the plant has sent its first ground truth (it runs, its node answers),
        or the run has already ended; a rig that does neither within ``timeout_s`` is an error."""
        if float(self.plant_settings.get("truth_rate_hz", 20.0)) <= 0:
            return  # no truth to wait for: the test's own frames may meet a node still starting
        deadline = time.monotonic() + timeout_s
        assert self._thread is not None
        while not self.plant.truth and self._thread.is_alive():
            if time.monotonic() > deadline:
                raise TimeoutError(f"the rig sent no ground truth within {timeout_s:g} s of its start")
            time.sleep(0.01)

    def wait(self, timeout_s: float | None = None) -> RunRecord:
        """The run's record once it has ended (``timeout_s`` of wall time at most)."""
        if self._thread is None:
            raise RuntimeError("the rig has not been started: call rig.run(duration_s) or rig.start(duration_s)")
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise TimeoutError(f"the rig did not finish within {timeout_s} s of wall time")
        if self._failure is not None:
            raise self._failure
        assert self.record is not None
        return self.record

    def run(self, duration_s: float) -> RunRecord:
        """Run ``duration_s`` simulated seconds and return the record."""
        return self.start(duration_s).wait()

    def _run_guarded(self, duration_s: float) -> None:
        try:
            with counting_warnings() as (warnings, errors):
                record = self._run_cosim(duration_s) if self.clock == "cosim" else self._run_in_process(duration_s)
            record.verdict = judge(
                {
                    "controller": {"ticks": record.ticks},
                    "health": {name: h.model_dump() for name, h in record.health.items()},
                    "exit_codes": {},
                    "failure": record.error or "",
                    "log_warnings": dict(warnings),
                    "log_errors": dict(errors),
                }
            )
            self.record = record
        except BaseException as exc:  # noqa: BLE001 - re-raised in the test's thread by wait()
            self._failure = exc

    def _run_cosim(self, duration_s: float) -> RunRecord:
        from workbench.cosim import run_cosim
        from workbench.recording.reader import Recording

        plant = dict(self.plant_settings)
        if self.plant.pending:
            own = json.loads(plant.get("scenario") or "[]")
            plant["scenario"] = json.dumps(
                own + [c.model_dump(mode="json", include={"kind", "at_sim_time_s", "payload_attached", "seed", "adc_bits"}) for c in self.plant.pending]
            )
        path = self._workdir / f"{self.rig_id}.mcap"
        run = run_cosim(
            controller=self._controller_settings(duration_s),
            plant=self.fiu.merge(plant),
            dsp=self._dsp_settings(),
            common={**self.common, "rig_id": self.rig_id},
            record=str(path),
        )
        rec = Recording.load(path, only=("plant/truth", "plant/events", "dsp/interrupt"))
        self.plant.truth = [GroundTruth.model_validate(d) for d in rec.data("plant/truth")]
        self.plant.events = [PlantEvent.model_validate(d) for d in rec.data("plant/events")]
        self.dsp.interrupts = [Interrupt.model_validate(d) for d in rec.data("dsp/interrupt")]
        return self._record(run, path)

    def _open_test_port(self) -> None:
        from protocol.keys import Keys
        from workbench.composition import _local_session

        keys = Keys(self.rig_id)
        self._session = _local_session()

        def keep(model: type[Any], into: list[Any]) -> Any:
            return lambda sample: into.append(decode(model, sample.payload.to_bytes()))

        for key, model, into in (
            (keys.truth, GroundTruth, self.plant.truth),
            (keys.plant_events, PlantEvent, self.plant.events),
            (keys.interrupt, Interrupt, self.dsp.interrupts),
        ):
            self._subs.append(self._session.declare_subscriber(key, keep(model, into)))

    def _run_in_process(self, duration_s: float) -> RunRecord:
        from workbench.composition import run_in_process

        session = self._session
        pending = list(self.plant.pending)

        def send_scenario() -> None:  # before tick 0, on the test port, as a tester would
            for cmd in pending:
                self._publish_scenario(cmd)

        common = {**self.common, "rig_id": self.rig_id, "clock": self.clock, "can_interface": "virtual", "can_channel": self.can_channel}
        plant = dict(self.plant_settings)
        if self.clock == "lockstep":  # nor the plant's SYNC watchdog (wall time) hold the valves of a starved lockstep run
            timeout = Timeouts.read(self.controller.get("timeouts")).lockstep_s
            rate = float(self.common.get("sample_rate_hz", 200.0))
            plant.setdefault("watchdog_periods", min(10_000, max(5, math.ceil(timeout * rate))))  # its upper bound
        run = run_in_process(
            controller=self._controller_settings(duration_s), plant=self.fiu.merge(plant), dsp=self._dsp_settings(), common=common, session=session,
            at_tick=(0, send_scenario) if pending else None, stop=self._stop,
        )  # fmt: skip
        return self._record(run, None)

    def _record(self, run: Any, recording: Path | None) -> RunRecord:
        return RunRecord(
            clock=self.clock,
            error=run.result.error,
            ticks=run.result.ticks,
            sim_time_s=run.result.sim_time_s,
            counters=dict(run.result.counters),
            columns={k: np.asarray(v) for k, v in run.controller.record.to_columns().items()},
            truth=list(self.plant.truth),
            events=list(self.plant.events),
            interrupts=list(self.dsp.interrupts),
            health=dict(run.health),
            wall_time_s=run.wall_time_s,
            recording=recording,
        )

    def close(self) -> None:
        """End what the rig opened: a ``lockstep``/``realtime`` run still going
        (a test that failed mid-run) is stopped, its services' threads joined;
        a co-simulated one is waited for, bounded."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive():
            self._thread.join(60.0)
        self.can.close()
        for sub in self._subs:
            sub.undeclare()
        self._subs.clear()
        if self._session is not None:
            self._session.close()
            self._session = None
