"""The real-time plant process dying mid-run (workbench/loss_grace.py): the
controller notices (no TPDO, no heartbeat), applies its plant-fault policy
(valves to zero, exit 3, its "plant fault" line) and only then does the run
end, with the launcher's one line naming the plant's death, and the verdict
FAIL. Once with an FMU whose ``doStep`` segfaults, once with a plant killed
by SIGKILL. No wall-clock assertion: the events are awaited, never timed."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from tests.plant.fmu.support import write_mapping
from tests.plant.fmu.test_fmu_loader_attacks import _crashing_fmu
from tests.rig.process_tree import descendants

pytestmark = [pytest.mark.rig, pytest.mark.slow]

CRASH_STEP = 600
"""The FMU's doStep crashes at this step (3 s of control at 200 Hz), after the controller's first tick is seen."""


@pytest.fixture(scope="module")
def crashing_fmu(tmp_path_factory: pytest.TempPathFactory) -> Path:
    if shutil.which("gcc") is None:
        pytest.skip("no C compiler")
    return _crashing_fmu(tmp_path_factory.mktemp("crash"))


def _up(tmp_path: Path, rig_id: str, *sets: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "workbench", "up", "--clock", "realtime", "--duration", "120", "--rig-id", rig_id]
        + ["--log-dir", str(tmp_path / "logs"), "--json", str(tmp_path / "summary.json")]
        + [a for s in sets for a in ("--set", s)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _assert_the_policy_acted(tmp_path: Path, proc: subprocess.Popen[str], stderr: str, launcher_line: str, plant_code: int) -> None:
    assert proc.returncode == 1, (proc.returncode, stderr)
    assert f"rig failed: {launcher_line}" in " ".join(stderr.split()), stderr
    assert "Traceback" not in stderr and "Fatal Python error" not in stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["exit_codes"]["controller"] == 3 and summary["exit_codes"]["plant"] == plant_code, summary["exit_codes"]
    assert summary["failure"] == launcher_line
    assert summary["verdict"]["verdict"] == "FAIL" and f"rig failed: {launcher_line}" in summary["verdict"]["reasons"]
    controller_log = (tmp_path / "logs" / "controller.log").read_text()
    assert re.search(r"plant fault: plant (did not answer SYNC|heartbeat lost)[^\n]*; valves to zero", controller_log), controller_log[-2000:]
    ended = re.search(r"run ended after \d+ ticks [^\n]*", controller_log)
    assert ended is not None and "'plant_faults': 1" in ended.group() and "'valves_zeroed': 1" in ended.group(), controller_log[-2000:]


@pytest.mark.timeout(300)
def test_a_segfault_in_the_fmus_dostep_is_met_by_the_plant_fault_policy(crashing_fmu: Path, tmp_path: Path) -> None:
    mapping = write_mapping(tmp_path, parameters={"fault_step": CRASH_STEP, "fault_kind": 4})
    proc = _up(tmp_path, f"crash-{uuid.uuid4().hex[:6]}", f"plant.model=fmu:{crashing_fmu}", f"plant.fmu_mapping={mapping}")
    _, stderr = proc.communicate(timeout=280)
    line = f"plant ended by SIGSEGV (Segmentation fault) in fmi2DoStep of FMU {crashing_fmu}"
    _assert_the_policy_acted(tmp_path, proc, stderr, line, -signal.SIGSEGV)
    assert "fmi2DoStep" in (tmp_path / "logs" / "plant.log").read_text()  # faulthandler's frames in the plant's log


def _plant_pid(up_pid: int) -> int:
    for pid in descendants(up_pid):
        try:
            argv = (Path("/proc") / str(pid) / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if b"plant_emulator" in argv:
            return pid
    raise AssertionError("no plant process below ralf-hil up")


@pytest.mark.timeout(300)
def test_a_plant_killed_mid_run_is_met_by_the_plant_fault_policy(tmp_path: Path) -> None:
    proc = _up(tmp_path, f"kill-{uuid.uuid4().hex[:6]}")
    assert proc.stderr is not None
    seen = ""
    while "all services ready" not in seen:  # the controller's first tick: the plant is running
        line = proc.stderr.readline()
        assert line, f"ralf-hil up ended before its first tick: {seen}"
        seen += line
    os.kill(_plant_pid(proc.pid), signal.SIGKILL)
    _, rest = proc.communicate(timeout=280)
    _assert_the_policy_acted(tmp_path, proc, seen + rest, "plant ended by SIGKILL (Killed)", -signal.SIGKILL)
