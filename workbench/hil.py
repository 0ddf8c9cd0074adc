"""The one rig API: :class:`HilRig` runs the rig, :class:`RunRecord` is what a run
leaves behind. The ``rig`` fixture of :mod:`workbench.pytest_plugin` is a
:class:`HilRig`; the experiments, the campaigns (:mod:`workbench.campaign.rigs`)
and ``ralf-hil up --clock cosim`` run theirs through it too. Importable without pytest.

:class:`HilRig` starts the rig in the clock and layout asked for:

``cosim`` (default)
    plant, controller and DSP co-simulated in one thread (:mod:`workbench.cosim`):
    fast and bit-for-bit deterministic. A run without ``outputs`` is recorded
    into an MCAP file (the :attr:`RunRecord.recording`) from which the truth,
    events and interrupts are read back. No CAN bus: the frames go straight to the node.
``lockstep`` / ``realtime``, one process (default)
    the three services composed in one process (:mod:`workbench.composition`):
    python-can's in-process ``virtual`` bus and an in-process zenoh session; the
    test port's truth and events and the DSP's interrupts arrive live, and the
    CAN bus (:attr:`HilRig.can`) takes the test's own frames and a ``canopen``
    master's SDO requests while the rig runs.
``lockstep`` / ``realtime``, ``processes=True``
    the three services as separate processes (:mod:`workbench.rig_processes`
    through :mod:`workbench.launcher`), CAN over ``udp_multicast`` on a port of
    the run's own: run it inside ``.ci/loopback-netns``. The test port's truth,
    events and interrupts arrive live on the launcher's session.

With ``outputs`` the run keeps its files there, under its ``name``: the
controller's record ``<name>.npz/.json/.timing.*/.tf.npz``, the plant's truth
``<name>.truth.npz``, the services' logs ``logs/<name>/`` (three processes) and,
with ``mcap=True``, the recording ``<name>.mcap``. A :class:`~workbench.rig_spec.RigSpec`
holds a run as frozen, picklable data (:meth:`HilRig.from_spec`), for fan-out.

Handles: :attr:`HilRig.plant` (the plant's test port: scenario commands,
ground truth, events), :attr:`HilRig.dsp` (its interrupts), :attr:`HilRig.can`
(send/receive frames, a ``canopen`` ``RemoteNode`` of the plant; one process
only) and the :class:`RunRecord` a run leaves behind. Settings are checked by
name before anything starts: an unknown one is one :class:`RigSettingError`.
A run that ends with a fault is not an exception: its record carries the
:attr:`RunRecord.error` and a verdict.
"""

from __future__ import annotations

import json
import math
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any, Literal

import numpy as np

from protocol.errors import ConfigError
from protocol.messages import ChannelTruth, ControllerStatus, GroundTruth, Interrupt, ParamChanged, PlantEvent, ScenarioCommand, decode, encode
from protocol.setting_groups import Timeouts
from protocol.setting_hints import unknown_setting
from protocol.settings import CommonSettings, ControllerSettings, DspSettings, PlantSettings, load_settings, retired
from workbench.fiu import FaultInsertion
from workbench.log_counts import counting_warnings
from workbench.params import ParamSchedule
from workbench.rig_record import Clock, Layout, RunRecord, truth_columns_of, truth_of
from workbench.rig_spec import RigSpec
from workbench.stimulus import Stimulus
from workbench.verdict import judge

__all__ = ["CLOCKS", "Clock", "HilRig", "NoCanBusError", "RigRunError", "RigSettingError", "RigSpec", "RunRecord", "check_settings"]

CLOCKS: tuple[Clock, ...] = ("cosim", "lockstep", "realtime")
MODELS: dict[str, type[CommonSettings]] = {"controller": ControllerSettings, "plant": PlantSettings, "dsp": DspSettings, "common": CommonSettings}
PLUMBING = frozenset({"clock", "can_interface", "can_channel", "rig_id", "record", "zenoh_connect", "zenoh_listen", "zenoh_mode"})
"""Chosen by the rig itself: a test that sets one gets an error, not a silently ignored value."""


class RigSettingError(ValueError):
    """A setting the rig does not have (or one it chooses itself), a bad clock, a bad value."""


class RigRunError(RuntimeError):
    """A run that could not be made (a setting the services refused at start), or, from
    :func:`workbench.campaign.rigs.map_rigs`, runs that ended with a fault."""


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


class PlantPort:
    """The plant's test port: scenario commands in, ground truth and events out."""

    def __init__(self, rig: HilRig) -> None:
        self._rig = rig
        self.pending: list[ScenarioCommand] = []
        self._sent = 0
        self.truth: list[GroundTruth] = []
        self.events: list[PlantEvent] = []
        self.channel_truth: list[ChannelTruth] = []
        self.param_changes: list[ParamChanged] = []
        """The changes of the plant's parameters it took (``plant/param_changes``), in order."""

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
        if self._rig.processes:
            raise NoCanBusError("a three-process rig's CAN bus is udp_multicast, not shared in this process: use the one-process layout for rig.can")

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
    """One rig for one run: configure, :meth:`run` (or :meth:`start`/:meth:`wait`), read its :class:`RunRecord`."""

    clock: Clock = "cosim"
    controller: dict[str, Any] = field(default_factory=dict)
    plant_settings: dict[str, Any] = field(default_factory=dict)
    dsp_settings: dict[str, Any] = field(default_factory=dict)
    common: dict[str, Any] = field(default_factory=dict)
    faults: str | Mapping[str, Any] | None = None
    """A link-fault scenario (:mod:`service_kit.link_faults`): a file path or its content as a mapping."""
    workdir: Path | None = None
    """Where the rig keeps what no one asked to keep (a temporary folder if None)."""
    processes: bool = False
    """``lockstep``/``realtime``: the three services as separate processes (:mod:`workbench.rig_processes`)."""
    name: str = ""
    """The run's name: the file stem of its outputs (default: the rig id)."""
    label: str = ""
    """Free text for tables and figures."""
    outputs: Path | None = None
    """Where the run's files go: ``<name>.npz/.json/.timing.*/.tf.npz`` (the controller's record),
    ``<name>.truth.npz`` (the plant's truth), ``logs/<name>/`` (three processes) and ``<name>.mcap`` (``mcap``)."""
    mcap: bool | str | Path | None = None
    """Record the run (co-simulated or three processes): True into ``<outputs>/<name>.mcap``, a path
    into that file, False not at all. None (default): a co-simulated run without ``outputs`` is
    recorded into the workdir (its truth, events and interrupts are read back from it), no other run is."""
    can_log: str | Path | None = None
    """Co-simulated and recorded: the CAN side also into python-can's ``.blf``/``.asc``/``.log``."""
    on_start: Callable[[Any], None] | None = None
    """Co-simulated: called with the controller before its first tick (a progress reader, which only reads it)."""
    meta: Mapping[str, Any] = field(default_factory=dict)
    """Extra facts for the recording's run record."""
    on_progress: Callable[[float], None] | None = None
    """Called with the simulated seconds advanced since its last call."""
    timeout_s: float | None = None
    """Three processes: the run's wall-clock allowance (default: from its simulated time)."""
    rig_id: str = ""
    """The rig's id, its ``ralf/<rig-id>`` key space (default: a fresh ``hil-<hex>``)."""
    duration_s: float | None = None
    """Simulated seconds of a :meth:`run` given none (else the controller's ``duration_s`` or ``repeats`` laps)."""
    stimulus: Stimulus = field(default_factory=Stimulus)
    """Stimulus profiles on the rig's inputs (:mod:`workbench.stimulus`, docs/stimulus.md), added to before the
    run (``rig.stimulus.step("valve.u1", 2.0, at_s=1.0, for_s=0.5)``): the controller's go into its ``stimulus``
    setting, the plant's into its scenario's ``stimulus`` section, both checked when the run starts."""
    param: ParamSchedule = field(default_factory=ParamSchedule)
    """Scripted parameter changes (:mod:`workbench.params`, docs/calibration.md), given before the run
    (``rig.param.set("controller.kp1", 8000.0, at_s=2.0)``, ``rig.param.set("plant.payload", 1.0, at_s=2.0)``):
    into the board's ``param_schedule`` setting, applied at its first step (the controller's tick, the plant's SYNC)
    at or after ``at_s``, listed in the record (``param_changes``, ``plant_param_changes``)."""

    @classmethod
    def from_spec(cls, spec: RigSpec, *, on_progress: Callable[[float], None] | None = None) -> HilRig:
        """The rig of a :class:`~workbench.rig_spec.RigSpec` (run it with :meth:`run`, no argument)."""
        rig = cls(
            clock=spec.clock, processes=spec.processes, name=spec.name, label=spec.label,
            controller=dict(spec.controller), plant_settings=dict(spec.plant), dsp_settings=dict(spec.dsp), common=dict(spec.common),
            faults=spec.faults, outputs=spec.outputs, mcap=spec.mcap, meta=dict(spec.meta), on_progress=on_progress, timeout_s=spec.timeout_s,
            duration_s=spec.duration_s, stimulus=Stimulus([dict(p) for p in spec.stimulus]), param=ParamSchedule(spec.params),
        )  # fmt: skip
        return rig

    def __post_init__(self) -> None:
        if self.clock not in CLOCKS:
            raise RigSettingError(f"unknown rig clock {self.clock!r} (cosim, lockstep, realtime)")
        if self.processes and self.clock == "cosim":
            raise RigSettingError("processes=True goes with the lockstep or realtime clock (the co-simulation is one thread)")
        if (self.processes or self.clock == "realtime") and any(
            str(part.get("can_bitrate", 0) or 0) != "0" for part in (self.common, self.controller, self.plant_settings)
        ):
            raise RigSettingError("can_bitrate (the simulated CAN wire) runs in simulated time in one process: clock='cosim', or 'lockstep' without processes")
        if self.mcap is True and self.outputs is None:
            raise RigSettingError("mcap=True records into <outputs>/<name>.mcap: give outputs (or mcap=PATH)")
        if self.mcap and self.layout == "one process":
            raise RigSettingError("a one-process run is not recorded: record a co-simulated run or one of three processes")
        if self.name and (self.name != Path(self.name).name or self.name in (".", "..")):
            raise RigSettingError(f"the run's name is a file stem, not a path: {self.name!r}")
        check_settings({"controller": self.controller, "plant": self.plant_settings, "dsp": self.dsp_settings, "common": self.common})
        self.rig_id = self.rig_id or f"hil-{uuid.uuid4().hex[:8]}"
        self.can_channel = f"ralf-{self.rig_id}-{uuid.uuid4().hex[:6]}"
        self.node_id = int(self.common.get("node_id", self.controller.get("node_id", 1)))
        self.plant = PlantPort(self)
        self.fiu = FaultInsertion(self)
        self.dsp = DspPort()
        self.can = CanPort(self)
        self.record: RunRecord | None = None
        self.controller_service: Any = None
        """After a run in this process (co-simulated or one process): the controller's service,
        its timing instruments (wake-up jitter, TET, hop stamps, misses) for a timing analysis."""
        self._session: Any = None
        self._subs: list[Any] = []
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._stop = threading.Event()
        """Set by :meth:`close`: a ``lockstep``/``realtime`` run still going ends at once."""
        self._own_workdir: Path | None = None

    @property
    def _workdir(self) -> Path:
        """The workdir, a temporary folder made on first need if none was given."""
        if self.workdir is not None:
            return Path(self.workdir)
        if self._own_workdir is None:
            self._own_workdir = Path(tempfile.mkdtemp(prefix="ralf-hil-test-"))
        return self._own_workdir

    def __enter__(self) -> HilRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def layout(self) -> Layout:
        """``cosim``, ``one process`` or ``three processes``."""
        return "cosim" if self.clock == "cosim" else "three processes" if self.processes else "one process"

    @property
    def stem(self) -> str:
        return self.name or self.rig_id

    # -- running -----------------------------------------------------------------------------
    def _controller_settings(self, duration_s: float | None) -> dict[str, Any]:
        own = dict(self.controller) if duration_s is None else {**self.controller, "duration_s": duration_s}
        profiles = self.stimulus.side("controller")
        if profiles:  # after the controller's own stimulus setting, if it has one
            given = own.get("stimulus") or []
            own["stimulus"] = json.dumps([*(json.loads(given) if isinstance(given, str) else given), *profiles])
        if self.faults is not None:
            own["fault_scenario"] = self.faults if isinstance(self.faults, str) else json.dumps(dict(self.faults))
        schedule = self.param.board_schedule("controller", own.get("param_schedule"))
        if schedule is not None:  # after the controller's own param_schedule setting, if it has one
            own["param_schedule"] = schedule
        return own

    def _dsp_settings(self) -> dict[str, Any]:
        """The DSP's settings with the fault scenario (its ``dsp_delay_s`` slows the board)."""
        if self.faults is None:
            return self.dsp_settings
        return {**self.dsp_settings, "fault_scenario": self.faults if isinstance(self.faults, str) else json.dumps(dict(self.faults))}

    def _plant_with_stimulus(self) -> dict[str, Any]:
        """The plant's settings with the channel faults (:attr:`fiu`) and the plant's stimulus profiles in its ``scenario``,
        and the scripted changes of its parameters (:attr:`param`) in its ``param_schedule``."""
        plant = self.fiu.merge(self.plant_settings)
        if self.stimulus.side("plant"):
            only_plant = Stimulus(self.stimulus.side("plant"))
            plant["scenario"] = json.dumps(only_plant.settings(scenario=plant.get("scenario"))["plant"]["scenario"])
        schedule = self.param.board_schedule("plant", plant.get("param_schedule"))
        if schedule is not None:  # after the plant's own param_schedule setting, if it has one
            plant["param_schedule"] = schedule
        return plant

    def _plant_with_pending(self) -> dict[str, Any]:
        """The plant's settings with the scenario commands and channel faults (:attr:`fiu`) given before the run in its ``scenario``."""
        plant = self._plant_with_stimulus()
        if self.plant.pending:
            own = json.loads(plant.get("scenario") or "[]")
            extra = [c.model_dump(mode="json", exclude_none=True, exclude={"seq", "sim_time_s", "wall_time_s"}) for c in self.plant.pending]
            if isinstance(own, dict):  # a scenario of sections: the commands join its own
                own["commands"] = list(own.get("commands", [])) + extra
                plant["scenario"] = json.dumps(own)
            else:
                plant["scenario"] = json.dumps(own + extra)
        return plant

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
            raise RuntimeError(f"a {self.layout} run takes scenario commands before its run only (give them before rig.run)")
        from protocol.keys import Keys

        self._session.put(Keys(self.rig_id).scenario, encode(cmd))

    def expected_sim_s(self, duration_s: float | None = None) -> float:
        """Simulated seconds the run lasts: ``duration_s``, or the controller's ``duration_s`` or ``repeats`` laps."""
        return RigSpec(self.stem, controller=self.controller, duration_s=duration_s if duration_s is not None else self.duration_s).expected_sim_s()

    def start(self, duration_s: float | None = None) -> HilRig:
        """Start a run of ``duration_s`` simulated seconds (None: the controller's ``duration_s``
        or ``repeats``) in the background (the CAN and test-port handles work while it runs;
        one process: returns once the plant runs, its first ground truth in); :meth:`wait` for its record."""
        if self._thread is not None:
            raise RuntimeError("this rig has already run; a test gets one run per rig")
        duration_s = duration_s if duration_s is not None else self.duration_s
        if duration_s is not None and not duration_s > 0:
            raise RigSettingError(f"duration_s must be positive, got {duration_s}")
        try:
            expected = self.expected_sim_s(duration_s)
        except ValueError as exc:
            raise RigSettingError(str(exc)) from None
        try:
            self.stimulus.plans()
        except ConfigError as exc:
            raise RigSettingError(" ".join(str(exc).split())) from None
        self.param.started = True
        if self.layout == "one process":
            self._open_test_port()
        self._thread = threading.Thread(target=self._run_guarded, args=(duration_s, expected), name="hil-rig", daemon=True)
        self._thread.start()
        if self.layout == "one process":
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

    def run(self, duration_s: float | None = None) -> RunRecord:
        """Run ``duration_s`` simulated seconds (None: the controller's ``duration_s`` or ``repeats``) and return the record."""
        return self.start(duration_s).wait()

    def _files(self) -> tuple[Path, Path] | None:
        """The controller record's stem and the plant's truth file, when the run keeps files."""
        where = self.outputs if self.outputs is not None else self._workdir if self.layout == "three processes" else None
        if where is None:
            return None
        record_path, truth_path = Path(where) / self.stem, Path(where) / f"{self.stem}.truth.npz"
        for stale in (truth_path, Path(str(record_path) + ".tf.npz")):
            stale.unlink(missing_ok=True)
        record_path.parent.mkdir(parents=True, exist_ok=True)
        return record_path, truth_path

    def _run_guarded(self, duration_s: float | None, expected: float) -> None:
        try:
            with counting_warnings() as (warnings, errors):
                started = time.monotonic()
                run = {"cosim": self._run_cosim, "one process": self._run_in_process, "three processes": self._run_processes}[self.layout]
                record = run(duration_s, expected)
                if self.layout != "three processes":
                    record.wall_time_s = time.monotonic() - started if self.outputs is not None else record.wall_time_s
                    if self.on_progress is not None:
                        self.on_progress(expected)
            record.log_warnings, record.log_errors = dict(warnings), dict(errors)
            record.verdict = judge(
                {
                    "controller": {"ticks": record.ticks},
                    "health": {name: h.model_dump() for name, h in record.health.items()},
                    "exit_codes": record.exit_codes if self.layout == "three processes" else {},
                    "failure": record.error or "",
                    "log_warnings": dict(warnings),
                    "log_errors": dict(errors),
                }
            )
            self.record = record
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread by wait()
            self._failure = exc

    def _run_cosim(self, duration_s: float | None, expected: float) -> RunRecord:
        from workbench.cosim import run_cosim
        from workbench.recording.reader import Recording

        files = self._files()
        plant = self._plant_with_pending()
        if files is not None:
            plant["truth_record"] = str(files[1])
        path = self._mcap_path()
        if path is None and self.mcap is None and self.outputs is None:
            path = self._workdir / f"{self.rig_id}.mcap"  # a test's run: its truth, events, interrupts read back
        try:
            run = run_cosim(
                controller=self._controller_settings(duration_s),
                plant=plant,
                dsp=self._dsp_settings(),
                common={**self.common, "rig_id": self.rig_id},
                record=str(path) if path is not None else None,
                can_log=str(self.can_log) if self.can_log is not None else None,
                record_metadata=({**self.meta, "run": self.stem} if self.outputs is not None else dict(self.meta) or None) if path is not None else None,
                on_start=self.on_start,
            )
        except (ConfigError, ValueError) as exc:
            raise RigRunError(f"run {self.stem!r} (co-simulation): {exc}") from None
        self.controller_service = run.controller
        if files is not None:
            run.controller.save(str(files[0]), run.result)
        if path is not None:
            rec = Recording.load(path, only=("plant/truth", "plant/events", "dsp/interrupt", "plant/channels", "plant/param_changes"))
            self.plant.truth = [GroundTruth.model_validate(d) for d in rec.data("plant/truth")]
            self.plant.events = [PlantEvent.model_validate(d) for d in rec.data("plant/events")]
            self.plant.channel_truth = [ChannelTruth.model_validate(d) for d in rec.data("plant/channels")]
            self.plant.param_changes = [ParamChanged.model_validate(d) for d in rec.data("plant/param_changes")]
            self.dsp.interrupts = [Interrupt.model_validate(d) for d in rec.data("dsp/interrupt")]
        return self._record(run, path, files)

    def _open_test_port(self) -> None:
        from protocol.keys import Keys
        from workbench.composition import _local_session

        self._session = _local_session()
        for key, callback in self._test_port(Keys(self.rig_id)):
            self._subs.append(self._session.declare_subscriber(key, callback))

    def _test_port(self, keys: Any) -> list[tuple[str, Callable[[Any], None]]]:
        """The test port's subscriptions: ground truth, plant events and interrupts into their lists."""

        def keep(model: type[Any], into: list[Any]) -> Callable[[Any], None]:
            return lambda sample: into.append(decode(model, sample.payload.to_bytes()))

        return [
            (keys.truth, keep(GroundTruth, self.plant.truth)),
            (keys.plant_events, keep(PlantEvent, self.plant.events)),
            (keys.channel_truth, keep(ChannelTruth, self.plant.channel_truth)),
            (keys.plant_param_changes, keep(ParamChanged, self.plant.param_changes)),
            (keys.interrupt, keep(Interrupt, self.dsp.interrupts)),
        ]

    def _run_in_process(self, duration_s: float | None, expected: float) -> RunRecord:
        from workbench.composition import run_in_process

        session = self._session
        pending = list(self.plant.pending)

        def send_scenario() -> None:  # before tick 0, on the test port, as a tester would
            for cmd in pending:
                self._publish_scenario(cmd)

        files = self._files()
        controller = self._controller_settings(duration_s)
        common = {**self.common, "rig_id": self.rig_id, "clock": self.clock, "can_interface": "virtual", "can_channel": self.can_channel}
        plant = self._plant_with_stimulus()  # the commands given before the run go on the test port, as a tester's would
        if files is not None:
            controller["run_record"] = str(files[0])  # the record streams to disk (controller.record.ChunkedRecord)
            plant["truth_record"] = str(files[1])
        if self.clock == "lockstep":  # nor the plant's SYNC watchdog (wall time) hold the valves of a starved lockstep run
            timeout = Timeouts.read(self.controller.get("timeouts")).lockstep_s
            rate = float(self.common.get("sample_rate_hz", 200.0))
            plant.setdefault("watchdog_periods", min(10_000, max(5, math.ceil(timeout * rate))))  # its upper bound
        run = run_in_process(
            controller=controller, plant=plant, dsp=self._dsp_settings(), common=common, session=session,
            at_tick=(0, send_scenario) if pending else None, stop=self._stop,
        )  # fmt: skip
        self.controller_service = run.controller
        if files is not None:
            run.controller.save(str(files[0]), run.result)
        return self._record(run, None, files)

    def _run_processes(self, duration_s: float | None, expected: float) -> RunRecord:
        from protocol.keys import Keys
        from workbench.rig_processes import run_processes

        files = self._files()
        assert files is not None  # three processes always keep their files (in the workdir if no outputs)
        where = files[0].parent
        controller = {**self._controller_settings(duration_s), "run_record": str(files[0])}
        plant = {**self._plant_with_pending(), "truth_record": str(files[1])}
        run = run_processes(
            rig_id=self.rig_id, clock=self.clock,
            settings={"controller": controller, "plant": plant, "dsp": self._dsp_settings(), "common": self.common},
            log_dir=where / "logs" / self.stem, expected_s=expected, on_progress=self.on_progress, timeout_s=self.timeout_s,
            mcap=self._mcap_path(), meta={**self.meta, "run": self.stem},
            listen=self._test_port(Keys(self.rig_id)),
        )  # fmt: skip
        loaded = _load_files(*files)
        result = loaded[1].get("result", {})
        error = run.failure or result.get("error") or None
        return RunRecord(
            clock=self.clock,
            error=error,
            ticks=int(result.get("ticks", 0)),
            sim_time_s=float(result.get("sim_time_s", 0.0)),
            counters=dict(result.get("counters", {})),
            columns=loaded[0],
            truth=list(self.plant.truth) or truth_of(loaded[3]),
            events=list(self.plant.events),
            plant_param_changes=self._plant_param_changes(run),
            interrupts=list(self.dsp.interrupts),
            health=run.health,
            wall_time_s=run.wall_time_s,
            recording=self._mcap_path(),
            channel_truth=list(self.plant.channel_truth),
            exit_codes=run.exit_codes,
            status=run.status,
            config=loaded[2],
            metadata=loaded[1],
            truth_columns=loaded[3],
            tf=loaded[4],
            record_path=files[0],
            truth_path=files[1],
            **self._identity(),
        )

    def _mcap_path(self) -> Path | None:
        """Where the run is recorded, if asked (``mcap`` True or a path)."""
        if self.mcap is True:
            return Path(self.outputs if self.outputs is not None else self._workdir) / f"{self.stem}.mcap"
        return Path(self.mcap) if isinstance(self.mcap, (str, Path)) else None

    def _identity(self) -> dict[str, Any]:
        return {
            "name": self.stem,
            "label": self.label,
            "layout": self.layout,
            "settings": {"controller": dict(self.controller), "plant": dict(self.plant_settings), "dsp": dict(self.dsp_settings), "common": dict(self.common)},
        }

    def _plant_param_changes(self, run: Any) -> list[dict[str, Any]]:
        """The changes of the plant's parameters: the co-simulated plant's own list, else its ``plant/param_changes`` events."""
        app = getattr(run, "plant", None)
        if app is not None and hasattr(app, "param_changes"):
            return [dict(c) for c in app.param_changes]
        return [
            {"sim_time_s": e.sim_time_s, "kind": e.kind, "fields": {k.removeprefix("plant."): v for k, v in e.fields.items()}, "who": e.who}
            for e in self.plant.param_changes
        ]

    def _record(self, run: Any, recording: Path | None, files: tuple[Path, Path] | None) -> RunRecord:
        """The record of a run made in this process (co-simulated or one process)."""
        from controller.record import to_jsonable

        if files is not None:
            columns, metadata, config, truth_columns, tf = _load_files(*files)
        else:
            columns = {k: np.asarray(v) for k, v in run.controller.record.to_columns().items()}
            metadata = {"result": to_jsonable(run.result.__dict__)}
            config = to_jsonable(run.controller.settings)
            truth_columns, tf = truth_columns_of(self.plant.truth), None
        truth = list(self.plant.truth) or truth_of(truth_columns)
        return RunRecord(
            clock=self.clock,
            error=run.result.error,
            ticks=run.result.ticks,
            sim_time_s=run.result.sim_time_s,
            counters=dict(run.result.counters),
            columns=columns,
            truth=truth,
            events=list(self.plant.events),
            plant_param_changes=self._plant_param_changes(run),
            interrupts=list(self.dsp.interrupts),
            health=dict(run.health),
            wall_time_s=run.wall_time_s,
            recording=recording,
            exit_codes={name: 0 for name in ("controller", "plant", "dsp")} if run.result.error is None else {},
            config=config,
            metadata=metadata,
            truth_columns=truth_columns,
            tf=tf,
            record_path=files[0] if files is not None else None,
            truth_path=files[1] if files is not None else None,
            status=_status(run.controller),
            recording_counts=getattr(run, "recording", None),
            channel_truth=list(self.plant.channel_truth),
            can_bus=getattr(run, "can_bus", None),
            **self._identity(),
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


def _status(controller: Any) -> ControllerStatus | None:
    """The controller's last status, if its port keeps one."""
    raw = getattr(controller.port, "status", None)
    return decode(ControllerStatus, raw) if isinstance(raw, bytes) else raw if isinstance(raw, ControllerStatus) else None


def _load_npz(path: Path) -> dict[str, np.ndarray] | None:
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def _load_files(
    record_path: Path, truth_path: Path
) -> tuple[dict[str, np.ndarray], dict[str, Any], dict[str, Any], dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    """What a run wrote: the controller record's columns, metadata and config (empty if it wrote none),
    the plant's truth columns and the TF downloads."""
    from controller.record import load_record

    if Path(str(record_path) + ".json").exists():
        rec = load_record(record_path)
        columns, metadata, config = {k: np.asarray(v) for k, v in rec.columns.items()}, rec.metadata, rec.config
    else:
        columns, metadata, config = {}, {}, {}
    return columns, metadata, config, _load_npz(truth_path) or {}, _load_npz(Path(str(record_path) + ".tf.npz"))
