"""How long the launcher lets the controller act on a service's death before
it ends the run itself (:func:`workbench.launcher.supervise`).

A rig's services can die mid-run (a crash inside the plant's FMU, a
SIGKILL, an exit). Two deaths have a policy in the controller, and the run
is meant to show it acting:

* **the plant**: no TPDO and no heartbeat any more; the controller declares
  a plant fault once its plant heartbeat timeout passes (``RALF_TIMEOUTS``
  ``plant_heartbeat_s``; lockstep: at least ``lockstep_s``, the controller's
  own rule in :mod:`controller.service`), commands the valves to zero and
  exits 3. The grace is that timeout plus the time any service is given to
  end (the launcher's ``stop_timeout_s``).
* **the DSP**: its zenoh liveliness token vanishes as its links close (at
  once for a dead process) and the controller's ``dsp_lost`` policy fires.
  Under ``stop`` the controller ends its run (exit 4): the grace is the time
  any service is given to end. Under ``count``, ``warn`` or ``degrade`` the
  controller would control on with its fallback parameters for the rest of
  the run, so the launcher ends the run at once (a service died: FAIL).

Every other death, and any death before the controller's first tick (the
controller is still waiting for its peers, up to ``startup_s``), ends the
run at once.
"""

from __future__ import annotations

from collections.abc import Mapping

from pydantic import ValidationError

from protocol.setting_groups import Policies, Timeouts


def controller_acts_on(env: Mapping[str, str], stop_timeout_s: float) -> dict[str, float]:
    """{service: grace in wall seconds} for each service whose death the
    controller answers with its own end, read from the controller's
    environment (``RALF_TIMEOUTS``, ``RALF_POLICIES``, ``RALF_CLOCK``). A
    setting the controller would refuse gives the defaults here (the
    controller then refuses to start, and nothing waits for it)."""
    try:
        timeouts = Timeouts.read(env.get("RALF_TIMEOUTS") or None)
    except (ValidationError, ValueError):
        timeouts = Timeouts()
    try:
        policies = Policies.read(env.get("RALF_POLICIES") or None)
    except (ValidationError, ValueError):
        policies = Policies()
    heartbeat_s = timeouts.plant_heartbeat_s
    if env.get("RALF_CLOCK") == "lockstep":
        heartbeat_s = max(heartbeat_s, timeouts.lockstep_s)
    grace = {"plant": heartbeat_s + stop_timeout_s}
    if policies.dsp_lost == "stop":
        grace["dsp"] = stop_timeout_s
    return grace
