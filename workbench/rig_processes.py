"""The three-process layout of :class:`workbench.hil.HilRig` (``processes=True``):
plant, controller and DSP as separate processes through :mod:`workbench.launcher`
(:meth:`~workbench.launcher.RigPlan.local`, :func:`~workbench.launcher.supervise`),
in lockstep or real time, with a rig id and a CAN (``udp_multicast``) port of
their own, so parallel runs never see each other's frames or keys. Run it
inside a loopback-only network namespace (``.ci/loopback-netns``).

Settings are given per service as field names of :mod:`protocol.settings`
(``{"oatf_mode": "fixed"}``); they become ``RALF_*`` variables (booleans as
``true``/``false``, tuples, lists and mappings as JSON). The controller's
``run_record`` and the plant's ``truth_record`` (chosen by the rig) write the
records; the services' logs go to the log folder. The run ends when the
controller exits (0 after its ``duration_s`` or ``repeats`` laps); the plant
(which writes its truth on the way out) and the DSP are then stopped. A
non-zero exit, a service dying early or a run past its wall-clock allowance is
the run's failure, with the exit codes and the tail of every log.
"""

from __future__ import annotations

import json
import threading
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.messages import ControllerStatus, Health

__all__ = ["ProcessRun", "env_of", "run_processes"]

SERVICES = ("controller", "plant", "dsp")

_PORT_LOCK = threading.Lock()
_PORTS_IN_USE: set[int] = set()


@dataclass
class ProcessRun:
    """How a three-process run went."""

    exit_codes: dict[str, int]
    failure: str
    """Empty when every service ended well; else what went wrong, the exit codes and every log's tail."""
    wall_time_s: float
    health: dict[str, Health] = field(default_factory=dict)
    status: ControllerStatus | None = None
    """The controller's last status."""


def _env_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (tuple, list)):
        return json.dumps(list(value))
    if isinstance(value, dict):  # a structured setting (RALF_OATF, RALF_DITHER, RALF_POLICIES)
        return json.dumps(value)
    return str(value)


def env_of(settings: Mapping[str, Any]) -> dict[str, str]:
    """A service's settings as its ``RALF_*`` environment variables."""
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


def run_processes(
    *,
    rig_id: str,
    clock: str,
    settings: Mapping[str, Mapping[str, Any]],
    log_dir: Path,
    expected_s: float,
    on_progress: Callable[[float], None] | None = None,
    timeout_s: float | None = None,
    mcap: Path | None = None,
    meta: Mapping[str, Any] | None = None,
    listen: Sequence[tuple[str, Callable[[Any], None]]] = (),
) -> ProcessRun:
    """Run the three services to the controller's end (see the module doc).

    ``settings``: by service (controller, plant, dsp, common). ``on_progress(s)``:
    simulated seconds advanced since the last call (``expected_s`` in all).
    ``timeout_s``: the wall-clock allowance (default: 90 s plus three times
    ``expected_s`` in lockstep, 1.5 times in real time). ``mcap``: record the
    run there (the tap starts before the services, so it holds their start-up;
    ``meta``: facts for its run record). ``listen``: ``(key, callback)`` pairs
    subscribed on the launcher's session for the run (a test port)."""
    from workbench.launcher import RigObserver, RigPlan, Supervision, supervise, tail

    port = _reserve_can_port(rig_id)
    plan = RigPlan.local(
        rig_id=rig_id,
        clock=clock,
        overrides={name: env_of(settings.get(name, {})) for name in SERVICES},
        common={"RALF_CAN_PORT": str(port), **env_of(settings.get("common", {}))},
    )
    if timeout_s is None:
        # lockstep runs 1-3x faster than real time here; allow for a loaded machine
        timeout_s = 90.0 + (3.0 * expected_s if clock == "lockstep" else 1.5 * expected_s)
    observer: RigObserver | None = None
    started = time.monotonic()
    reported = 0.0
    health: dict[str, Health] = {}
    status: ControllerStatus | None = None
    recording: Any = None
    subs: list[Any] = []

    def progress(_sup: Supervision, status: Any) -> None:
        nonlocal reported
        if on_progress is not None and status is not None:
            now = min(float(status.sim_time_s), expected_s)
            if now > reported:
                on_progress(now - reported)
                reported = now

    try:
        observer = RigObserver(plan)
        subs = [observer.session.declare_subscriber(key, callback) for key, callback in listen]
        if mcap is not None:
            from workbench.recording.tap import RigRecording

            recording = RigRecording(plan, str(mcap), observer.session, clock=clock, **dict(meta or {}))
        watched = observer
        sup = supervise(plan, log_dir, lambda: watched.status, timeout_s=timeout_s, on_poll=progress, stop_timeout_s=20.0)
        time.sleep(0.1)
        health, status = dict(observer.health), observer.status
    finally:
        if recording is not None:
            recording.close()
        for sub in subs:
            sub.undeclare()
        if observer is not None:
            observer.close()
        _release_can_port(port)
    procs, exit_codes, failure = sup.procs, sup.exit_codes, sup.failure
    if failure.startswith("no end after"):
        failure = f"no end after {timeout_s:.0f} s wall time (expected {expected_s:.0f} s simulated)"
    wall = time.monotonic() - started
    if on_progress is not None and expected_s > reported:
        on_progress(expected_s - reported)
    bad = {k: v for k, v in exit_codes.items() if v != 0}
    text = ""
    if failure or bad or len(exit_codes) < len(SERVICES):
        logs = "\n".join(f"--- {name} ({procs[name].log_path}) ---\n{tail(procs[name].log_path, 20)}" for name in procs)
        text = f"rig {rig_id!r}: {failure or 'non-zero exit'}; exit codes {exit_codes}\n{logs}"
    return ProcessRun(exit_codes=dict(exit_codes), failure=text, wall_time_s=wall, health=health, status=status)
