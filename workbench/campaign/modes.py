"""Run modes: how one resolved run is carried out.

A run mode is a function ``(RunPoint) -> dict`` (the metrics row, see
:mod:`workbench.campaign.metrics`), registered under a name with
:func:`register_mode`; a spec picks one per run (``mode:``, default
:data:`DEFAULT_MODE`). The function runs on a Dask worker, so it must be
importable there (a module-level function of an installed module) and must
choose every bit of per-run plumbing itself: the point's rig id
(``sw-<key>``, its own ``ralf/<rig-id>`` namespace), the bus, the records.

``lockstep`` (default)
    The three services composed in one process (:func:`workbench.composition.run_in_process`):
    python-can's in-process ``virtual`` bus, an in-process zenoh session, one
    plant step per SYNC. Deterministic for given settings, also on a loaded
    host: no SYNC is ever resent (the virtual bus loses none; a late answer
    resent would step the plant twice), and the plant's heartbeat and the
    SYNC may be as late as the lockstep timeout (``controller.timeouts``' ``lockstep_s``)
    before the controller declares a fault or the plant's watchdog holds the
    valves (``valves_held_samples`` in the row counts any). No network.
``onrig``
    The three-process rig of the experiments (:func:`workbench.experiments.onrig.runner.run_rig`):
    separate processes over zenoh on loopback and CAN over ``udp_multicast``
    (run it inside the loopback-only namespace, ``.ci/loopback-netns``), lockstep.

``cosim`` (the default)
    The three boards co-simulated in one thread (:func:`workbench.cosim.run_cosim`),
    bit-identical to the three-process lockstep rig.

Adding a mode is one registration::

    @register_mode("NAME")
    def run_name(point: RunPoint) -> dict[str, Any]:
        ...
        return run_metrics(columns, truth, counters, sample_period_s=..., wall_s=...)
"""

from __future__ import annotations

import math
import tempfile
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from controller.monitors import INPUT_MONITORS
from protocol.record_paths import truth_file
from protocol.setting_groups import Timeouts
from workbench.campaign.metrics import detection_metrics, run_metrics
from workbench.campaign.spec import DEFAULT_MODE, VOLATILE, RunMode, RunPoint, get_mode, known_modes, register_mode

__all__ = ["DEFAULT_MODE", "RunFailed", "RunMode", "get_mode", "known_modes", "register_mode", "run_point"]


class RunFailed(RuntimeError):
    """The rig ran but ended with a fault (the controller's error)."""


def run_point(point: RunPoint) -> dict[str, Any]:
    """Worker entry: the point's mode, run."""
    return get_mode(point.mode)(point)


def _own(settings: dict[str, Any]) -> dict[str, Any]:
    """A service's settings without the plumbing and the clock the mode chooses."""
    return {k: v for k, v in settings.items() if k not in VOLATILE and k != "clock"}


def _load_npz(path: Path) -> dict[str, np.ndarray] | None:
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as data:
        return {k: data[k] for k in data.files}


def _one_process_row(point: RunPoint, run_rig: Callable[..., Any], controller: dict[str, Any], plant: dict[str, Any], common: dict[str, Any]) -> dict[str, Any]:
    """Run one rig in this process (``run_rig``: the co-simulation or the one-process
    composition, the same signature), the plant's truth through a temporary file; its row."""
    s = point.settings
    with tempfile.TemporaryDirectory(prefix="ralf-sweep-") as tmp:
        truth_path = truth_file(Path(tmp) / "run")
        started = time.perf_counter()
        run = run_rig(controller=controller, plant={**plant, "truth_record": str(truth_path)}, dsp=_own(s["dsp"]), common=common)
        wall = time.perf_counter() - started
        if run.result.error:
            raise RunFailed(f"run {point.key} ended with a fault: {run.result.error}")
        truth = _load_npz(truth_path)
    columns = run.controller.record.to_columns()
    period = 1.0 / float(s["controller"]["sample_rate_hz"])
    row = run_metrics(columns, truth, run.result.counters, sample_period_s=period, wall_s=wall)
    inputs = getattr(run.controller, "inputs", None)
    if inputs is not None:  # the input monitors on: when each fired (a fault sweep's figure)
        row.update(detection_metrics(inputs.events, INPUT_MONITORS, period))
    return row


@register_mode("cosim")
def run_cosim_point(point: RunPoint) -> dict[str, Any]:
    """The three boards co-simulated in one thread (:mod:`workbench.cosim`): bit-identical to the
    three-process lockstep rig, no processes, no sockets, so runs on one worker never disturb
    each other and a loaded host changes only the wall time."""
    from workbench.cosim import run_cosim

    s = point.settings
    return _one_process_row(point, run_cosim, _own(s["controller"]), _own(s["plant"]), {"rig_id": point.rig_id})


@register_mode("lockstep")
def run_lockstep(point: RunPoint) -> dict[str, Any]:
    """One process, lockstep, in-process bus and zenoh session (see the module doc)."""
    from workbench.composition import run_in_process

    s = point.settings
    controller = _own(s["controller"])
    # Wall-clock supervision means nothing for a lockstep run's result; on a loaded host a
    # thread can starve for over a second (measured: 1.0-3.2 s with four rigs on two cores).
    # The controller allows its plant heartbeat the lockstep timeout in lockstep; the plant's
    # SYNC watchdog (2 s of wall time in lockstep) gets as long here: tripped, it holds the valves.
    timeout_s = Timeouts.read(controller.get("timeouts")).lockstep_s
    plant = _own(s["plant"])
    plant["watchdog_periods"] = max(int(plant["watchdog_periods"]), math.ceil(timeout_s * float(s["plant"]["sample_rate_hz"])))
    common = {"clock": "lockstep", "can_interface": "virtual", "can_channel": f"{point.rig_id}-{uuid.uuid4().hex[:6]}", "rig_id": point.rig_id}
    return _one_process_row(point, run_in_process, controller, plant, common)


@register_mode("onrig")
def run_onrig(point: RunPoint) -> dict[str, Any]:
    """Three processes (plant, controller, DSP) over zenoh and udp_multicast CAN, lockstep."""
    from rich.console import Console

    from workbench.experiments.framework import ExperimentContext
    from workbench.experiments.onrig.runner import RigRun, run_rig

    with tempfile.TemporaryDirectory(prefix="ralf-sweep-") as tmp:
        ctx = ExperimentContext(out_dir=Path(tmp), mode="lockstep", show_progress=False, console=Console(stderr=True, quiet=True))
        spec = RigRun(point.rig_id, controller=point.changed("controller"), plant=point.changed("plant"), dsp=point.changed("dsp"))
        res = run_rig(ctx, spec, in_process=False)
        counters = res.record.metadata.get("result", {}).get("counters", {})
        return run_metrics(res.record.columns, res.truth, counters, sample_period_s=res.sample_period_s, wall_s=res.wall_time_s)
