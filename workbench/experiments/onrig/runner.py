"""Running the rig for an experiment (the analysis the experiments share is in :mod:`workbench.experiments.analysis`).

:func:`run_rig` runs one rig to completion and returns its records
(:class:`RigResult`); :func:`workbench.campaign.rigs.run_rigs` runs several
independent ones on the campaign engine (:mod:`workbench.campaign.rigs`: one Dask task per run, a local
cluster of one worker per core unless ``ralf-hil experiment --scheduler``
names a cluster).

The co-simulation (the default, ``ctx.mode == "cosim"``)
    Plant, controller and DSP cores called in order each tick in this
    thread (:func:`workbench.cosim.run_cosim`): the same cores and codecs as the
    three-process rig in lockstep, and the same records bit for bit, with
    no processes, sockets or threads. ``in_process`` does not matter then.
    The records are written to the same places as below.

The full rig (``--mode lockstep`` or ``--mode realtime``)
    The three services as separate processes through :mod:`workbench.launcher`
    (``RigPlan.local``, ``start_service``, ``stop_service``), in the
    experiment's clock mode (``ctx.mode``: ``lockstep`` by default, or
    ``realtime``), with a rig id and a CAN (udp_multicast) port of their own,
    so parallel runs never see each other's frames or keys. The
    controller's ``RALF_RUN_RECORD`` writes ``records/<name>.npz/.json`` (plus
    ``.timing.*`` and ``.tf.npz`` with the transfer-function downloads) and
    the plant's ``RALF_TRUTH_RECORD`` the ground truth ``records/<name>.truth.npz``,
    both below the experiment's output directory; the services' logs go to
    ``records/logs/<name>/``. The runner waits for the controller to exit
    (it exits 0 after ``RALF_DURATION_S`` or ``RALF_REPEATS`` laps), then
    stops the plant (which writes its record on the way out) and the DSP.
    Any non-zero exit, a service dying early, or a run past its wall-clock
    allowance raises :class:`RigRunError` with the exit codes and the tail of
    every log.

One process (``in_process=True``)
    The same services composed in one process (:func:`workbench.composition.run_in_process`:
    python-can's ``virtual`` bus, an in-process zenoh session), lockstep
    unless ``ctx.mode`` says otherwise; faster, for ``--quick`` runs and the
    tests. The records are written to the same places.

Settings are given per service as field names of :mod:`protocol.settings`
(``{"oatf_mode": "fixed"}``); for the processes they become ``RALF_*``
variables (booleans as ``true``/``false``, tuples as JSON).
"""

from __future__ import annotations

import json
import threading
import time
import uuid
import zlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from controller.record import RunRecord, load_record
from controller.trajectory import DEFAULT_TRAJECTORY_PATH, load_trajectory, sample_trajectory
from workbench.experiments.analysis import centred_median as centred_median
from workbench.experiments.analysis import costs_over as costs_over
from workbench.experiments.framework import ExperimentContext

__all__ = [
    "THESIS_BATCH_SIZE",
    "RigResult",
    "RigRun",
    "RigRunError",
    "centred_median",
    "costs_over",
    "lap_seconds",
    "run_rig",
]

FloatArray = npt.NDArray[np.float64]

THESIS_BATCH_SIZE = 20
"""The batch size l the experiments use (thesis: 20-50 samples; its identification runs: 20)."""

SERVICES = ("controller", "plant", "dsp")

_PORT_LOCK = threading.Lock()
_PORTS_IN_USE: set[int] = set()


class RigRunError(RuntimeError):
    """A rig run failed: a service exited non-zero, died early, or the run overran its allowance."""


@dataclass(frozen=True)
class RigRun:
    """One run: a name (file stem, unique within the experiment) and each service's settings."""

    name: str
    controller: Mapping[str, Any] = field(default_factory=dict)
    plant: Mapping[str, Any] = field(default_factory=dict)
    dsp: Mapping[str, Any] = field(default_factory=dict)
    common: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    """Free text for tables and figures."""

    def expected_sim_s(self) -> float:
        """Simulated seconds the run lasts (the controller's duration_s, or repeats laps)."""
        c = self.controller
        if c.get("duration_s") is not None:
            return float(c["duration_s"])
        repeats = int(c.get("repeats", 0))
        if repeats <= 0:
            raise ValueError(f"run {self.name!r}: set controller duration_s or repeats")
        return repeats * lap_seconds(float(c.get("tip_speed_in_s", 5.0)), c.get("trajectory") or None)


@dataclass
class RigResult:
    """What one run left behind, loaded."""

    spec: RigRun
    record: RunRecord
    """The controller's per-tick record (``t_s``, set-points, deflections, commands, OATF and identifier columns)."""
    truth: dict[str, np.ndarray]
    """The plant's ground truth at its truth rate: ``sim_time_s``, ``modal_frequencies_hz`` (n, 2), ``theta_rad``, ..."""
    tf: dict[str, np.ndarray] | None
    """The DSP's transfer-function downloads: ``freqs_hz``, ``sim_time_s``, ``H11_mag`` ... ``Htot_mag``."""
    record_path: Path
    truth_path: Path
    wall_time_s: float
    in_process: bool
    mode: str
    health: dict[str, dict[str, Any]] = field(default_factory=dict)
    exit_codes: dict[str, int] = field(default_factory=dict)

    @property
    def t_s(self) -> FloatArray:
        return np.asarray(self.record["t_s"], dtype=float)

    @property
    def sample_period_s(self) -> float:
        t = self.t_s
        return float(t[1] - t[0]) if t.size > 1 else 0.005

    @property
    def deflections(self) -> FloatArray:
        """``(n, 2)`` link deflections (in) as the controller measured them."""
        return np.column_stack([self.record["defl1_in"], self.record["defl2_in"]]).astype(float)

    def true_mode_hz(self, t_s: npt.ArrayLike, mode: int = 0) -> FloatArray:
        """The plant's true natural frequency of ``mode`` at controller times ``t_s``.

        The plant samples a tick after advancing one period, so controller
        tick ``k`` (``t = k Ts``) sees the plant at ``(k + 1) Ts``.
        """
        ts = np.asarray(self.truth["sim_time_s"], dtype=float)
        f = np.asarray(self.truth["modal_frequencies_hz"], dtype=float)[:, mode]
        return np.interp(np.asarray(t_s, dtype=float) + self.sample_period_s, ts, f)

    def true_theta(self, t_s: npt.ArrayLike) -> FloatArray:
        """True joint angles θ1, θ2 (rad) at controller times, ``(n, 2)``."""
        ts = np.asarray(self.truth["sim_time_s"], dtype=float)
        th = np.asarray(self.truth["theta_rad"], dtype=float)
        t = np.asarray(t_s, dtype=float) + self.sample_period_s
        return np.column_stack([np.interp(t, ts, th[:, 0]), np.interp(t, ts, th[:, 1])])

    def summary(self) -> dict[str, Any]:
        """Run facts for results.json."""
        counters = self.record.metadata.get("result", {}).get("counters", {})
        keep = ("batches_sent", "interrupts", "deadline_misses", "samples_dropped", "oatf_updates", "tf_downloads", "stale_episodes")
        return {
            "name": self.spec.name,
            "label": self.spec.label,
            "settings": {"controller": dict(self.spec.controller), "plant": dict(self.spec.plant), "dsp": dict(self.spec.dsp)},
            "rig": "co-simulation (workbench.cosim)"
            if self.mode == "cosim"
            else "one process (workbench.composition)"
            if self.in_process
            else "three processes (workbench.launcher)",
            "mode": self.mode,
            "sim_time_s": float(len(self.record) * self.sample_period_s),
            "wall_time_s": round(self.wall_time_s, 2),
            "counters": {k: counters[k] for k in keep if k in counters},
            "exit_codes": self.exit_codes,
            "record": str(self.record_path.name),
        }


# --------------------------------------------------------------------------- laps


def lap_seconds(speed_in_s: float = 5.0, trajectory: str | Path | None = None, sample_period_s: float = 0.005) -> float:
    """Duration of one lap of the trajectory at ``speed_in_s`` (42 s at 5 in/s, 51 s at 4 in/s for the loop)."""
    traj = load_trajectory(trajectory or DEFAULT_TRAJECTORY_PATH)
    sampled = sample_trajectory(traj, sample_period_s, speed_in_per_s=speed_in_s)
    return len(sampled.joints.phi) * sample_period_s


def _env_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return json.dumps(list(value))
    if isinstance(value, dict):  # a structured setting (RALF_OATF, RALF_DITHER, RALF_POLICIES)
        return json.dumps(value)
    if isinstance(value, Path):
        return str(value)
    return str(value)


def _env(settings: Mapping[str, Any]) -> dict[str, str]:
    return {f"RALF_{k.upper()}": _env_value(v) for k, v in settings.items() if v is not None}


def _reserve_can_port(rig_id: str) -> int:
    """A udp_multicast port no other run of this process is using (probing from the rig id's hash)."""
    with _PORT_LOCK:
        port = 43200 + zlib.crc32(rig_id.encode()) % 20000
        while port in _PORTS_IN_USE:
            port = 43200 + (port - 43200 + 1) % 20000
        _PORTS_IN_USE.add(port)
        return port


def _release_can_port(port: int) -> None:
    with _PORT_LOCK:
        _PORTS_IN_USE.discard(port)


def _load(spec: RigRun, record_path: Path, truth_path: Path) -> tuple[RunRecord, dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    record = load_record(record_path)
    if not truth_path.exists():
        raise RigRunError(f"run {spec.name!r}: the plant wrote no ground truth ({truth_path})")
    with np.load(truth_path, allow_pickle=False) as data:
        truth = {k: data[k] for k in data.files}
    tf_path = Path(str(record_path) + ".tf.npz")
    tf = None
    if tf_path.exists():
        with np.load(tf_path, allow_pickle=False) as data:
            tf = {k: data[k] for k in data.files}
    return record, truth, tf


def _rig_result(
    ctx: ExperimentContext,
    spec: RigRun,
    record_path: Path,
    truth_path: Path,
    *,
    wall_time_s: float,
    in_process: bool,
    health: dict[str, dict[str, Any]],
    exit_codes: dict[str, int],
) -> RigResult:
    """Load what a finished run wrote and wrap it with how the run went."""
    record, truth, tf = _load(spec, record_path, truth_path)
    return RigResult(
        spec=spec,
        record=record,
        truth=truth,
        tf=tf,
        record_path=record_path,
        truth_path=truth_path,
        wall_time_s=wall_time_s,
        in_process=in_process,
        mode=ctx.mode,
        health=health,
        exit_codes=exit_codes,
    )


# --------------------------------------------------------------------------- runners


def run_rig(
    ctx: ExperimentContext,
    spec: RigRun,
    *,
    in_process: bool = False,
    on_progress: Callable[[float], None] | None = None,
    timeout_s: float | None = None,
) -> RigResult:
    """Run one rig to completion (see the module doc); ``on_progress(sim_seconds_advanced)`` reports progress."""
    record_path = ctx.path(f"records/{spec.name}")
    truth_path = ctx.path(f"records/{spec.name}.truth.npz")
    for stale in (truth_path, Path(str(record_path) + ".tf.npz")):
        if stale.exists():
            stale.unlink()
    controller = {**spec.controller, "run_record": str(record_path)}
    plant = {**spec.plant, "truth_record": str(truth_path)}
    dsp = dict(spec.dsp)
    expected = spec.expected_sim_s()
    if ctx.mode == "cosim":
        return _run_cosim(ctx, spec, controller, plant, dsp, record_path, truth_path, expected, on_progress)
    if in_process:
        if ctx.record:
            ctx.log(f"run {spec.name!r} runs in one process (--quick): not recorded (co-simulated and three-process runs are)")
        return _run_in_process(ctx, spec, controller, plant, dsp, record_path, truth_path, expected, on_progress)
    return _run_processes(ctx, spec, controller, plant, dsp, record_path, truth_path, expected, on_progress, timeout_s)


def _run_in_process(
    ctx: ExperimentContext,
    spec: RigRun,
    controller: dict[str, Any],
    plant: dict[str, Any],
    dsp: dict[str, Any],
    record_path: Path,
    truth_path: Path,
    expected: float,
    on_progress: Callable[[float], None] | None,
) -> RigResult:
    from workbench.composition import run_in_process

    started = time.monotonic()
    common = {**spec.common, "clock": ctx.mode}
    run = run_in_process(
        controller={
            **{k: v for k, v in controller.items() if k != "run_record"},
            "run_record": str(record_path),
        },  # the record streams to disk (controller.record.ChunkedRecord)
        plant=plant,
        dsp=dsp,
        common=common,
    )
    return _finish_in_thread(ctx, spec, run, "one process", record_path, truth_path, expected, on_progress, started)


def _run_cosim(
    ctx: ExperimentContext,
    spec: RigRun,
    controller: dict[str, Any],
    plant: dict[str, Any],
    dsp: dict[str, Any],
    record_path: Path,
    truth_path: Path,
    expected: float,
    on_progress: Callable[[float], None] | None,
) -> RigResult:
    from protocol.errors import ConfigError
    from workbench.cosim import run_cosim

    started = time.monotonic()
    try:
        run = run_cosim(
            controller={k: v for k, v in controller.items() if k != "run_record"},
            plant=plant,
            dsp=dsp,
            common=dict(spec.common),
            record=str(ctx.path(f"records/{spec.name}.mcap")) if ctx.record else None,
            record_metadata={"experiment": ctx.experiment.name if ctx.experiment else "exp", "run": spec.name},
        )
    except (ConfigError, ValueError) as exc:
        raise RigRunError(f"run {spec.name!r} (co-simulation): {exc}") from None
    return _finish_in_thread(ctx, spec, run, "co-simulation", record_path, truth_path, expected, on_progress, started)


def _finish_in_thread(
    ctx: ExperimentContext,
    spec: RigRun,
    run: Any,
    what: str,
    record_path: Path,
    truth_path: Path,
    expected: float,
    on_progress: Callable[[float], None] | None,
    started: float,
) -> RigResult:
    """The end of a run made in this process (one process or co-simulated):
    its fault raised, its record saved, its result read back from disk."""
    if run.result.error:
        raise RigRunError(f"run {spec.name!r} ({what}) ended with a fault: {run.result.error}")
    run.controller.save(str(record_path), run.result)
    if on_progress is not None:
        on_progress(expected)
    wall = time.monotonic() - started
    health = {k: v.model_dump(mode="json") for k, v in run.health.items()}
    return _rig_result(ctx, spec, record_path, truth_path, wall_time_s=wall, in_process=True, health=health, exit_codes={name: 0 for name in SERVICES})


def _run_processes(
    ctx: ExperimentContext,
    spec: RigRun,
    controller: dict[str, Any],
    plant: dict[str, Any],
    dsp: dict[str, Any],
    record_path: Path,
    truth_path: Path,
    expected: float,
    on_progress: Callable[[float], None] | None,
    timeout_s: float | None,
) -> RigResult:
    from workbench.launcher import RigObserver, RigPlan, Supervision, supervise, tail

    exp = ctx.experiment.name if ctx.experiment else "exp"
    rig_id = f"x-{exp}-{spec.name}"[:55] + "-" + uuid.uuid4().hex[:6]
    rig_id = "".join(c if c.isalnum() or c in "-_" else "-" for c in rig_id)
    port = _reserve_can_port(rig_id)
    log_dir = ctx.path(f"records/logs/{spec.name}/x").parent
    plan = RigPlan.local(
        rig_id=rig_id,
        clock=ctx.mode,
        overrides={"controller": _env(controller), "plant": _env(plant), "dsp": _env(dsp)},
        common={"RALF_CAN_PORT": str(port), **_env(spec.common)},
    )
    if timeout_s is None:
        # lockstep runs 1-3x faster than real time here; allow for a loaded machine
        timeout_s = 90.0 + (3.0 * expected if ctx.mode == "lockstep" else 1.5 * expected)
    observer: RigObserver | None = None
    started = time.monotonic()
    reported = 0.0
    health: dict[str, dict[str, Any]] = {}
    recording: Any = None

    def progress(_sup: Supervision, status: Any) -> None:
        nonlocal reported
        if on_progress is not None and status is not None:
            now = min(float(status.sim_time_s), expected)
            if now > reported:
                on_progress(now - reported)
                reported = now

    try:
        observer = RigObserver(plan)
        if ctx.record:  # the tap starts before the services, so it holds their start-up
            from workbench.recording.tap import RigRecording

            recording = RigRecording(plan, str(ctx.path(f"records/{spec.name}.mcap")), observer.session, experiment=exp, run=spec.name, clock=ctx.mode)
        watched = observer
        sup = supervise(plan, log_dir, lambda: watched.status, timeout_s=timeout_s, on_poll=progress, stop_timeout_s=20.0)
        time.sleep(0.1)
        health = {k: v.model_dump(mode="json") for k, v in observer.health.items()}
    finally:
        if recording is not None:
            recording.close()
        if observer is not None:
            observer.close()
        _release_can_port(port)
    procs, exit_codes, failure = sup.procs, sup.exit_codes, sup.failure
    if failure.startswith("no end after"):
        failure = f"no end after {timeout_s:.0f} s wall time (expected {expected:.0f} s simulated)"
    wall = time.monotonic() - started
    if on_progress is not None and expected > reported:
        on_progress(expected - reported)
    bad = {k: v for k, v in exit_codes.items() if v != 0}
    if failure or bad or len(exit_codes) < len(SERVICES):
        logs = "\n".join(f"--- {name} ({procs[name].log_path}) ---\n{tail(procs[name].log_path, 20)}" for name in procs)
        what = failure or "non-zero exit"
        raise RigRunError(f"run {spec.name!r} on rig {rig_id!r} failed: {what}; exit codes {exit_codes}\n{logs}")
    return _rig_result(ctx, spec, record_path, truth_path, wall_time_s=wall, in_process=False, health=health, exit_codes=exit_codes)
