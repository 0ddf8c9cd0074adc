"""``ralf-hil fault`` on a running rig (``ralf-hil up --scenarios``, real
time, three processes, mutual TLS and access rules as every local rig):
with the tester's credentials the plant takes the fault and says so; a fault
it cannot apply is refused in one line; with the tool's credentials the
access rules drop the command and the tool says it had no answer."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import uuid
from pathlib import Path

import pytest

pytestmark = pytest.mark.rig


def _env(path: Path) -> dict[str, str]:
    return dict(line.split("=", 1) for line in path.read_text().splitlines() if "=" in line)


def _fault(env_file: Path, *argv: str, timeout_s: float) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **_env(env_file)}
    return subprocess.run(
        [sys.executable, "-m", "workbench", "fault", *argv, "--timeout", str(timeout_s)], env=env, capture_output=True, text=True, timeout=timeout_s + 60
    )


@pytest.mark.timeout(400)
def test_the_tester_inserts_a_fault_into_a_running_rig_and_the_tool_cannot(tmp_path: Path) -> None:
    rig_id = f"fault-{uuid.uuid4().hex[:6]}"
    up = subprocess.Popen(
        [sys.executable, "-m", "workbench", "up", "--scenarios", "--duration", "300", "--rig-id", rig_id, "--log-dir", str(tmp_path / "logs")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    found = threading.Event()

    def read() -> None:
        assert up.stdout is not None
        for line in up.stdout:
            lines.append(line)
            if "tools' credentials in " in line:
                found.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert found.wait(120), "".join(lines)
        tool_env = Path(re.search(r"tools' credentials in (\S+)", "".join(lines)).group(1))  # type: ignore[union-attr]
        tester_env = tool_env.parent / "tester.env"
        assert tester_env.exists()

        ok = _fault(tester_env, "short_ground", "AI3", "--at", "1", "--for", "2", timeout_s=150)
        assert ok.returncode == 0, ok.stderr
        assert ok.stdout.strip() == f"inserted on rig {rig_id!r}: AI3 short_ground from 1 s until 3 s"

        refused = _fault(tester_env, "lost_bits", "AI2", "--bits", "15", timeout_s=30)
        assert refused.returncode == 1
        assert refused.stderr.strip() == "ralf-hil fault: the plant refused AI2 lost_bits bits=15 from 0 s: lost_bits 15 leaves no bit of the 12-bit A/D"

        denied = _fault(tool_env, "open", "AI4", timeout_s=4)
        assert denied.returncode == 1
        assert denied.stderr.count("\n") == 1 and "no answer from the plant" in denied.stderr and "this session's user: tool" in denied.stderr

        bad = _fault(tester_env, "noise", "AO1", "--sigma-v", "0.1", timeout_s=4)
        assert bad.returncode == 2 and bad.stderr.startswith("ralf-hil fault: noise on AO1: 'noise' is not a fault of a D/A output")
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(90)
        except subprocess.TimeoutExpired:
            up.kill()
            up.wait(30)
        reader.join(10)
    plant_log = (tmp_path / "logs" / "plant.log").read_text()
    assert "plant event channel_fault_added: AI3 short_ground from 1 s until 3 s" in plant_log
    assert plant_log.count("plant event channel_fault_added") == 1  # resent until answered, taken once
    assert "AI4 open" not in plant_log  # the tool's command never reached the plant
