"""``ralf-hil up --live`` with ``controller.param_commands``: the three-process
rig under its access rules, Foxglove's parameter panel through a WebSocket
client from the specification (its sets as the tool role, on a session of
the run's ``tool.env``), and ``ralf-hil param`` with the same credentials."""

from __future__ import annotations

import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.live.test_live_params import _exchange, _values
from workbench.launcher import free_tcp_ports

pytestmark = [pytest.mark.rig, pytest.mark.slow, pytest.mark.timeout(300)]
RIG = "liveparams"


def _tool_env(line: str) -> dict[str, str]:
    match = re.search(r"tools' credentials in (\S+)", line)
    assert match, line
    env = dict(os.environ)
    for row in Path(match.group(1)).read_text().splitlines():
        name, _, value = row.partition("=")
        env[name] = value
    return env


def test_the_panel_and_the_command_line_change_a_running_rigs_gain_as_tools(tmp_path: Path) -> None:
    port = free_tcp_ports(1)[0]
    cmd = [sys.executable, "-m", "workbench", "up", "--clock", "lockstep", "--duration", "3600", "--rig-id", RIG, "--live", f"127.0.0.1:{port}",
           "--set", "controller.param_commands=true", "--set", "controller.param_write_roles=tester,tool",
           "--json", str(tmp_path / "summary.json")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        line = ""
        while "tools' credentials in" not in line:
            line = proc.stdout.readline()
            assert line, "up ended before naming its credentials"
        env = _tool_env(line)
        deadline = time.monotonic() + 120
        table: dict[str, object] = {}
        while not table and time.monotonic() < deadline:  # the controller answers once it runs
            _, answers, _ = asyncio.run(_exchange(f"ws://127.0.0.1:{port}", [{"op": "getParameters", "parameterNames": [], "id": "all"}]))
            table = _values(answers["all"]) if "all" in answers else {}
        assert "controller.kp1" in table, table
        _, answers, _ = asyncio.run(
            _exchange(f"ws://127.0.0.1:{port}", [{"op": "setParameters", "parameters": [{"name": "controller.kp2", "value": 12000.0}], "id": "set"}])
        )
        assert _values(answers["set"])["controller.kp2"] == 12000.0
        listed = subprocess.run([sys.executable, "-m", "workbench", "param", "get", "controller.kp2"], env=env, capture_output=True, text=True, timeout=60)
        assert listed.returncode == 0 and listed.stdout.startswith("controller.kp2 = 12000 mV/rad (limits 0 .. 1e+06)"), listed.stderr
        refused = subprocess.run(
            [sys.executable, "-m", "workbench", "param", "set", "controller.kp2", "-3"], env=env, capture_output=True, text=True, timeout=60
        )
        assert refused.returncode == 1 and refused.stderr.count("\n") == 1
        assert "outside its limits 0 .. 1e+06 mV/rad" in refused.stderr
        proc.send_signal(signal.SIGINT)  # up stops the services as asked, its summary and the controller's record written
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err[-2000:]  # stopped as asked (SIGINT)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["live"]["param_sets_taken"] == 1 and summary["live"]["param_sets_refused"] == 0
    counters = summary["health"]["controller"]["counters"]  # the controller's last health
    assert counters["param_changes_applied"] == 1 and counters["param_sets_refused"] == 1
