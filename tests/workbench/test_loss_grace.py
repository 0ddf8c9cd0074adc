"""A service's death mid-run and the controller's policy (workbench/loss_grace.py,
workbench/launcher.py ``supervise``): a dead plant leaves the controller its
heartbeat timeout plus the stop time to end its run itself, bounded; a dead
DSP only under the ``dsp_lost`` policy ``stop``; every other death, and any
before the first tick, ends the run at once.

The services here are stand-ins (small Python processes), no network: the
plant kills itself with SIGKILL at once; the controller ends with the exit
code it is given only once the launcher says it grants the grace (a file the
poll callback writes), so no test depends on how fast anything runs."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.messages import ControllerStatus
from workbench import launcher
from workbench.launcher import RigPlan, ServiceProcess, Supervision, supervise
from workbench.loss_grace import controller_acts_on

KILL_SELF = "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"
LIVE = "import time\nwhile True: time.sleep(0.05)"


def _ends_on(go: Path, code: int) -> str:
    return f"import os, sys, time\nwhile not os.path.exists({str(go)!r}): time.sleep(0.02)\nsys.exit({code})"


def _rig(monkeypatch: pytest.MonkeyPatch, scripts: dict[str, str]) -> None:
    def start(plan: RigPlan, name: str, log_dir: Path) -> ServiceProcess:
        log_dir.mkdir(parents=True, exist_ok=True)
        log_path = log_dir / f"{name}.log"
        with open(log_path, "wb") as log:
            popen = subprocess.Popen([sys.executable, "-c", scripts[name]], stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        return ServiceProcess(name=name, popen=popen, log_path=log_path)

    monkeypatch.setattr(launcher, "start_service", start)


def _run(tmp_path: Path, ticks: int = 5, stop_timeout_s: float = 2.0, **env: str) -> Supervision:
    go = tmp_path / "go"

    def on_poll(sup: Supervision, _status: object) -> None:
        if sup.policy_grace_s is not None:
            go.touch()

    plan = RigPlan.local(rig_id="loss-grace", overrides={"controller": env})
    status = ControllerStatus(seq=0, sim_time_s=0.0, ticks=ticks, loop_rate_hz=200.0, batches_sent=0, interrupts=0)
    return supervise(plan, tmp_path / "logs", lambda: status, timeout_s=120, on_poll=on_poll, poll_s=0.02, stop_timeout_s=stop_timeout_s)


def test_the_grace_is_derived_from_the_controllers_timeouts() -> None:
    assert controller_acts_on({}, 10.0) == {"plant": 11.0}
    assert controller_acts_on({"RALF_TIMEOUTS": "plant_heartbeat_s=0.25"}, 10.0) == {"plant": 10.25}
    assert controller_acts_on({"RALF_CLOCK": "lockstep", "RALF_TIMEOUTS": "lockstep_s=5,plant_heartbeat_s=2"}, 1.0) == {"plant": 6.0}
    assert controller_acts_on({"RALF_POLICIES": "dsp_lost=stop"}, 3.0) == {"plant": 4.0, "dsp": 3.0}
    assert controller_acts_on({"RALF_TIMEOUTS": "plant_heartbeat_s=nonsense"}, 10.0) == {"plant": 11.0}  # the controller refuses it itself


def test_a_dead_plant_waits_for_the_controllers_plant_fault(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _rig(monkeypatch, {"dsp": LIVE, "plant": KILL_SELF, "controller": _ends_on(tmp_path / "go", 3)})
    sup = _run(tmp_path, stop_timeout_s=60.0, RALF_TIMEOUTS="plant_heartbeat_s=0.5")  # a grace no loaded host outlasts
    assert sup.policy_grace_s == pytest.approx(60.5)
    assert sup.failure == "plant ended by SIGKILL (Killed)"
    assert sup.exit_codes["controller"] == 3 and sup.exit_codes["plant"] == -signal.SIGKILL


def test_a_controller_that_does_not_answer_is_stopped_after_the_grace(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _rig(monkeypatch, {"dsp": LIVE, "plant": KILL_SELF, "controller": LIVE})
    sup = _run(tmp_path, stop_timeout_s=0.1, RALF_TIMEOUTS="plant_heartbeat_s=0.01")
    assert sup.failure == "plant ended by SIGKILL (Killed); the controller did not end its run within 0.1 s of it"
    assert sup.exit_codes["controller"] == -signal.SIGTERM


def test_a_dead_plant_before_the_first_tick_ends_the_run_at_once(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _rig(monkeypatch, {"dsp": LIVE, "plant": KILL_SELF, "controller": _ends_on(tmp_path / "go", 3)})
    sup = _run(tmp_path, ticks=0)
    assert sup.policy_grace_s is None and sup.failure == "plant ended by SIGKILL (Killed)"
    assert sup.exit_codes["controller"] == -signal.SIGTERM  # stopped: it was still waiting for its peers


@pytest.mark.parametrize(("policy", "waits"), [("degrade", False), ("stop", True)])
def test_a_dead_dsp_waits_only_under_the_stop_policy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, policy: str, waits: bool) -> None:
    _rig(monkeypatch, {"dsp": KILL_SELF, "plant": LIVE, "controller": _ends_on(tmp_path / "go", 4)})
    sup = _run(tmp_path, stop_timeout_s=60.0, RALF_POLICIES=f"dsp_lost={policy}")
    assert sup.failure == "dsp ended by SIGKILL (Killed)"
    assert (sup.policy_grace_s is not None) is waits
    assert sup.exit_codes["controller"] == (4 if waits else -signal.SIGTERM)
