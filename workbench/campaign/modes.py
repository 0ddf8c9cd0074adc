"""Run modes: how one resolved run is carried out.

A run mode is a function ``(RunPoint) -> dict`` (the metrics row, see
:mod:`workbench.campaign.metrics`), registered under a name with
:func:`register_mode`; a spec picks one per run (``mode:``, default
:data:`DEFAULT_MODE`). The function runs on a Dask worker, so it must be
importable there (a module-level function of an installed module) and must
leave the per-run plumbing (rig id, bus, record files) to the rig it makes
(:class:`workbench.hil.HilRig`, which gives each run its own).

``lockstep`` (default)
    The three services composed in one process (:class:`workbench.hil.HilRig`, lockstep):
    python-can's in-process ``virtual`` bus, an in-process zenoh session, one
    plant step per SYNC. Deterministic for given settings, also on a loaded
    host: no SYNC is ever resent (the virtual bus loses none; a late answer
    resent would step the plant twice), and the plant's heartbeat and the
    SYNC may be as late as the lockstep timeout (``controller.timeouts``' ``lockstep_s``)
    before the controller declares a fault or the plant's watchdog holds the
    valves (``valves_held_samples`` in the row counts any). No network.
``onrig``
    The three-process rig (:class:`workbench.hil.HilRig` with ``processes=True``):
    separate processes over zenoh on loopback and CAN over ``udp_multicast``
    (run it inside the loopback-only namespace, ``.ci/loopback-netns``), lockstep.

``cosim`` (the default)
    The three boards co-simulated in one thread (:class:`workbench.hil.HilRig`, ``cosim``),
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
from pathlib import Path
from typing import Any

from controller.monitors import INPUT_MONITORS
from protocol.setting_groups import Timeouts
from workbench.campaign.metrics import detection_metrics, run_metrics
from workbench.campaign.spec import DEFAULT_MODE, VOLATILE, RunMode, RunPoint, get_mode, known_modes, register_mode
from workbench.hil import PLUMBING, HilRig

__all__ = ["DEFAULT_MODE", "RunFailed", "RunMode", "get_mode", "known_modes", "register_mode", "run_point"]


class RunFailed(RuntimeError):
    """The rig ran but ended with a fault (the controller's error)."""


def run_point(point: RunPoint) -> dict[str, Any]:
    """Worker entry: the point's mode, run."""
    return get_mode(point.mode)(point)


def _own(settings: dict[str, Any]) -> dict[str, Any]:
    """A service's settings without the plumbing and the clock the rig chooses."""
    return {k: v for k, v in settings.items() if k not in VOLATILE and k not in PLUMBING}


def _row(point: RunPoint, **rig: Any) -> dict[str, Any]:
    """Run the point's rig (:class:`HilRig` of ``rig``), its plant's truth and controller record through a temporary folder; its row."""
    with tempfile.TemporaryDirectory(prefix="ralf-sweep-") as tmp, HilRig(rig_id=point.rig_id, name="run", outputs=Path(tmp), **rig) as hil:
        rec = hil.run()
        inputs = getattr(hil.controller_service, "inputs", None)
    if rec.error:
        raise RunFailed(f"run {point.key} ended with a fault: {rec.error}")
    period = 1.0 / float(point.settings["controller"]["sample_rate_hz"])
    row = run_metrics(rec.columns, rec.truth_columns or None, rec.counters, sample_period_s=period, wall_s=rec.wall_time_s)
    if inputs is not None:  # the input monitors on: when each fired (a fault sweep's figure)
        row.update(detection_metrics(inputs.events, INPUT_MONITORS, period))
    return row


@register_mode("cosim")
def run_cosim_point(point: RunPoint) -> dict[str, Any]:
    """The three boards co-simulated in one thread (:mod:`workbench.cosim`): bit-identical to the
    three-process lockstep rig, no processes, no sockets, so runs on one worker never disturb
    each other and a loaded host changes only the wall time."""
    s = point.settings
    return _row(point, clock="cosim", controller=_own(s["controller"]), plant_settings=_own(s["plant"]), dsp_settings=_own(s["dsp"]))


@register_mode("lockstep")
def run_lockstep(point: RunPoint) -> dict[str, Any]:
    """One process, lockstep, in-process bus and zenoh session (see the module doc)."""
    s = point.settings
    controller = _own(s["controller"])
    # Wall-clock supervision means nothing for a lockstep run's result; on a loaded host a
    # thread can starve for over a second (measured: 1.0-3.2 s with four rigs on two cores).
    # The controller allows its plant heartbeat the lockstep timeout in lockstep; the plant's
    # SYNC watchdog (2 s of wall time in lockstep) gets as long here: tripped, it holds the valves.
    timeout_s = Timeouts.read(controller.get("timeouts")).lockstep_s
    plant = _own(s["plant"])
    plant["watchdog_periods"] = max(int(plant["watchdog_periods"]), math.ceil(timeout_s * float(s["plant"]["sample_rate_hz"])))
    return _row(point, clock="lockstep", controller=controller, plant_settings=plant, dsp_settings=_own(s["dsp"]))


@register_mode("onrig")
def run_onrig(point: RunPoint) -> dict[str, Any]:
    """Three processes (plant, controller, DSP) over zenoh and udp_multicast CAN, lockstep."""
    changed = {"controller": point.changed("controller"), "plant_settings": point.changed("plant"), "dsp_settings": point.changed("dsp")}
    return _row(point, clock="lockstep", processes=True, **changed)
