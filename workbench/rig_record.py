"""What a rig run leaves behind: :class:`RunRecord`, the one record of every
run of :class:`workbench.hil.HilRig` (a test's, an experiment's, a campaign's,
``ralf-hil up --clock cosim``'s), importable without pytest.

It holds the controller's per-tick record (its columns, configuration and
metadata, as :func:`controller.record.load_record` reads them), the plant's
ground truth (as messages and as the columns of its ``.truth.npz``), the
plant's events, the DSP's interrupts, each service's last health message, the
DSP's transfer-function downloads, how the run was laid out and where its
files are. It is plain data (numpy arrays, pydantic messages, paths): it
pickles, so a campaign worker sends it back whole.

The controller's own per-tick record class (:class:`controller.record.RunRecord`)
is a different thing of the same name; :meth:`RunRecord.controller_record`
gives it for code that takes one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from controller import record as controller_record
from protocol.messages import ChannelTruth, ControllerStatus, GroundTruth, Health, Interrupt, PlantEvent
from workbench.verdict import Verdict

__all__ = ["LAYOUT_TEXT", "Clock", "Layout", "RunRecord", "truth_columns_of", "truth_of"]

Clock = Literal["cosim", "lockstep", "realtime"]
Layout = Literal["cosim", "one process", "three processes"]
LAYOUT_TEXT: dict[str, str] = {
    "cosim": "co-simulation (workbench.cosim)",
    "one process": "one process (workbench.composition)",
    "three processes": "three processes (workbench.launcher)",
}
"""How each layout is named in a run's facts (:meth:`RunRecord.run_facts`)."""
FACT_COUNTERS = ("batches_sent", "interrupts", "deadline_misses", "samples_dropped", "oatf_updates", "tf_downloads", "stale_episodes")
"""The counters a run's facts (``results.json``) keep."""
FloatArray = npt.NDArray[np.float64]


def truth_columns_of(truth: Sequence[GroundTruth]) -> dict[str, np.ndarray]:
    """The ground-truth messages as the columns the plant writes to its ``.truth.npz``
    (:meth:`plant_emulator.service.PlantApplication.save_truth`)."""
    if not truth:
        return {}
    n_modes = min(len(t.modal_frequencies_hz) for t in truth)
    return {
        "sim_time_s": np.array([t.sim_time_s for t in truth]),
        "modal_frequencies_hz": np.array([t.modal_frequencies_hz[:n_modes] for t in truth]),
        "damping_ratios": np.array([t.damping_ratios[:n_modes] for t in truth]),
        "deflections_in": np.array([t.deflections_in for t in truth]),
        "theta_rad": np.array([t.theta_rad for t in truth]),
        "tip_in": np.array([t.tip_in for t in truth]),
        "payload_attached": np.array([t.payload_attached for t in truth]),
        "valves_held": np.array([t.valves_held for t in truth]),
    }


def truth_of(columns: dict[str, np.ndarray]) -> list[GroundTruth]:
    """Ground-truth messages from the plant's truth columns (``seq`` is the row; no sender wall time)."""
    if "sim_time_s" not in columns:
        return []
    c = columns
    return [
        GroundTruth(
            seq=i,
            sim_time_s=float(c["sim_time_s"][i]),
            wall_time_s=0.0,
            modal_frequencies_hz=tuple(float(v) for v in c["modal_frequencies_hz"][i]),
            damping_ratios=tuple(float(v) for v in c["damping_ratios"][i]),
            deflections_in=(float(c["deflections_in"][i][0]), float(c["deflections_in"][i][1])),
            theta_rad=(float(c["theta_rad"][i][0]), float(c["theta_rad"][i][1])),
            tip_in=(float(c["tip_in"][i][0]), float(c["tip_in"][i][1])),
            payload_attached=bool(c["payload_attached"][i]),
            valves_held=bool(c["valves_held"][i]) if "valves_held" in c else False,
        )
        for i in range(len(c["sim_time_s"]))
    ]


@dataclass
class RunRecord:
    """What a run leaves behind."""

    clock: Clock
    """The clock the run had: cosim, lockstep or realtime."""
    error: str | None
    """The controller's fault (or, three processes, what went wrong with a service, with its log's tail); None when the run ended normally."""
    ticks: int
    """Control ticks run."""
    sim_time_s: float
    """Simulated time at the end of the run (s)."""
    counters: dict[str, int]
    """The controller's counters by name (each listed in docs/pytest-plugin.md)."""
    columns: dict[str, np.ndarray]
    """The controller's record: one array per column (``t_s``, ``defl1_in``, ``defl2_in``, ``phi1``, ``u1_v``, ``f_id_hz``, ...)."""
    truth: list[GroundTruth]
    """The plant's ground truth (its test port, or read back from its recording or truth file), in order."""
    events: list[PlantEvent]
    """The plant's events (hard stops, watchdog, payload), in order (a co-simulated run with ``outputs``: only when recorded, ``mcap=True``)."""
    interrupts: list[Interrupt]
    """The DSP's interrupts (identified modes, one per batch), in order (a co-simulated run with ``outputs``: only when recorded, ``mcap=True``)."""
    health: dict[str, Health]
    """Each service's last health message, by service name."""
    wall_time_s: float
    """Wall-clock time the run took (s)."""
    recording: Path | None = None
    """The run's MCAP file, if it was recorded (open it in Foxglove with docs/foxglove-layout.json)."""
    verdict: Verdict | None = None
    """The run's verdict (:mod:`workbench.verdict`: PASS, DEGRADED, FAIL or INVALID, with what went wrong);
    the ``rig`` fixture fails a test whose run is INVALID (no tick, or a dead plant model) unless
    the test is marked ``rig_invalid_ok``."""
    name: str = ""
    """The run's name (the file stem of its outputs)."""
    label: str = ""
    """Free text for tables and figures."""
    layout: Layout = "cosim"
    """How the rig ran: ``cosim`` (one thread), ``one process`` or ``three processes``."""
    settings: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The settings the run was given, by service (controller, plant, dsp, common)."""
    exit_codes: dict[str, int] = field(default_factory=dict)
    """Each service's exit code (three processes; 0 for each when a run in this process ended normally)."""
    config: dict[str, Any] = field(default_factory=dict)
    """The controller's settings as its record stores them."""
    metadata: dict[str, Any] = field(default_factory=dict)
    """The controller record's metadata (its run result, trajectory, ...)."""
    truth_columns: dict[str, np.ndarray] = field(default_factory=dict)
    """The plant's ground truth as columns (its ``.truth.npz``): ``sim_time_s``, ``modal_frequencies_hz`` (n, 2), ``theta_rad``, ..."""
    tf: dict[str, np.ndarray] | None = None
    """The DSP's transfer-function downloads the controller kept (``freqs_hz``, ``sim_time_s``, ``H11_mag`` ...), with ``outputs``."""
    record_path: Path | None = None
    """The controller record's stem (``<outputs>/<name>``: ``.npz``, ``.json``, ``.timing.*``, ``.tf.npz``), with ``outputs``."""
    truth_path: Path | None = None
    """The plant's truth file (``<outputs>/<name>.truth.npz``), with ``outputs``."""
    status: ControllerStatus | None = None
    """The controller's last status message (co-simulated or three processes)."""
    log_warnings: dict[str, int] = field(default_factory=dict)
    """WARNING log records during the run, by service (``rig`` for the rest)."""
    log_errors: dict[str, int] = field(default_factory=dict)
    """ERROR-or-worse log records during the run, by service."""
    recording_counts: dict[str, int] | None = None
    """The recorder's counters (messages and frames written, dropped), when the run was recorded."""
    channel_truth: list[ChannelTruth] = field(default_factory=list)
    """The plant's channels beside their faults (true and faulted volts, the faults acting), in order: only
    while it has channel faults (docs/fault-insertion.md; a co-simulated run with ``outputs``: only when recorded)."""
    plant_param_changes: list[dict[str, Any]] = field(default_factory=list)
    """The changes of the plant's parameters it took (docs/calibration.md), in order, as :attr:`param_changes`: each
    ``sim_time_s`` (of the SYNC from which), ``kind``, ``who`` and ``fields`` (``payload``: 1 attached, 0 released)."""
    can_bus: dict[str, Any] | None = None
    """The simulated CAN wire's figures (co-simulation or one-process lockstep with ``can_bitrate`` set; None without the wire,
    docs/can-wire.md "In the simulated rig"): ``bitrate``, ``restbus``, ``busy_mean_pct`` and ``busy_max_pct``
    (busy share per 100 ms window), ``frames_per_s``, ``bits_per_s``, ``sync_to_tpdo1_us`` and ``sync_to_rpdo1_us``
    (``min``, ``p50``, ``max``: SYNC queued to TPDO1 at the controller, to RPDO1 at the plant), ``late_tpdo1`` (after the
    deadline: samples held), ``queuing_delay_us`` per identifier (``n``, ``min``, ``p50``, ``max``)."""

    def __getstate__(self) -> dict[str, Any]:
        """Pickled light: a truth list that is only the truth columns again goes as the columns alone."""
        state = dict(self.__dict__)
        if self.truth and self.truth_columns and self.truth[0].wall_time_s == 0.0 and len(self.truth) == len(self.truth_columns.get("sim_time_s", ())):
            state["truth"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        if state.get("truth") is None:
            state["truth"] = truth_of(state.get("truth_columns", {}))
        self.__dict__.update(state)

    def summary(self) -> str:
        """One line: what the run covered and its verdict."""
        verdict = self.verdict.line() if self.verdict is not None else "not judged"
        wire = ""
        if self.can_bus is not None:
            b = self.can_bus
            wire = (
                f"; CAN {b['bitrate'] // 1000} kbit/s busy {b['busy_mean_pct']:.1f} % (max {b['busy_max_pct']:.1f} %), "
                f"{b['frames_per_s']:.0f} frames/s, {b['late_tpdo1']} late TPDO1"
            )
        return f"{self.clock} run: {self.ticks} ticks ({self.sim_time_s:.2f} s simulated), {len(self.interrupts)} interrupts{wire}; {verdict}"

    @property
    def max_abs_deflection_in(self) -> float:
        """The largest measured tip deflection, either link (in)."""
        return float(np.max(np.abs(np.concatenate([self.columns["defl1_in"], self.columns["defl2_in"]])))) if self.ticks else float("nan")

    def true_first_mode_hz(self) -> np.ndarray:
        """The plant's true first modal frequency at each truth sample (Hz)."""
        return np.array([t.modal_frequencies_hz[0] for t in self.truth])

    @property
    def param_changes(self) -> list[dict[str, Any]]:
        """The parameter changes the controller took (docs/calibration.md), in order: each
        ``sim_time_s`` (of the first tick that uses it), ``kind`` (``xcp``, ``param``, ``schedule``),
        ``who`` and ``fields`` (the physical values); from the run's ``config_changes``."""
        changes = self.metadata.get("result", {}).get("config_changes", [])
        return [dict(c) for c in changes if c.get("kind") in ("xcp", "param", "schedule")]

    @property
    def t_s(self) -> FloatArray:
        """The controller's tick times (s)."""
        return np.asarray(self.columns["t_s"], dtype=float)

    @property
    def sample_period_s(self) -> float:
        """The controller's sample period (s), from its tick times."""
        t = self.t_s
        return float(t[1] - t[0]) if t.size > 1 else 0.005

    @property
    def deflections(self) -> FloatArray:
        """``(n, 2)`` link deflections (in) as the controller measured them."""
        return np.column_stack([self.columns["defl1_in"], self.columns["defl2_in"]]).astype(float)

    def true_mode_hz(self, t_s: npt.ArrayLike, mode: int = 0) -> FloatArray:
        """The plant's true natural frequency of ``mode`` at controller times ``t_s``.

        The plant samples a tick after advancing one period, so controller
        tick ``k`` (``t = k Ts``) sees the plant at ``(k + 1) Ts``.
        """
        ts = np.asarray(self.truth_columns["sim_time_s"], dtype=float)
        f = np.asarray(self.truth_columns["modal_frequencies_hz"], dtype=float)[:, mode]
        return np.interp(np.asarray(t_s, dtype=float) + self.sample_period_s, ts, f)

    def true_theta(self, t_s: npt.ArrayLike) -> FloatArray:
        """True joint angles θ1, θ2 (rad) at controller times, ``(n, 2)``."""
        ts = np.asarray(self.truth_columns["sim_time_s"], dtype=float)
        th = np.asarray(self.truth_columns["theta_rad"], dtype=float)
        t = np.asarray(t_s, dtype=float) + self.sample_period_s
        return np.column_stack([np.interp(t, ts, th[:, 0]), np.interp(t, ts, th[:, 1])])

    def output(self, ending: str) -> Path:
        """One of the run's files: ``<outputs>/<name><ending>`` (``.npz``, ``.tf.npz``, ``.truth.npz``, ...)."""
        if self.record_path is None:
            raise ValueError(f"run {self.name!r} kept no files (give the rig outputs)")
        return self.record_path.with_name(self.record_path.name + ending)

    def controller_record(self) -> controller_record.RunRecord:
        """The controller's record as :func:`controller.record.load_record` gives it (for code that takes one)."""
        return controller_record.RunRecord(columns=self.columns, config=self.config, metadata=self.metadata)

    def run_facts(self) -> dict[str, Any]:
        """The run's facts for an experiment's results.json."""
        counters = self.metadata.get("result", {}).get("counters", self.counters)
        return {
            "name": self.name,
            "label": self.label,
            "settings": {k: dict(self.settings.get(k, {})) for k in ("controller", "plant", "dsp")},
            "rig": LAYOUT_TEXT[self.layout],
            "mode": self.clock,
            "sim_time_s": float(len(self.columns.get("t_s", ())) * self.sample_period_s) if "t_s" in self.columns else 0.0,
            "wall_time_s": round(self.wall_time_s, 2),
            "counters": {k: counters[k] for k in FACT_COUNTERS if k in counters},
            "exit_codes": self.exit_codes,
            "record": self.record_path.name if self.record_path is not None else "",
            **({"can_bus": self.can_bus} if self.can_bus is not None else {}),
        }
