"""Every subcommand given a bad argument answers with one line on stderr,
no traceback, exit code 2, before anything starts (no rig, no file)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from workbench.progress import messages

BAD = {
    "up misspelt setting value": ["up", "--set", "controller.oatf_mode=adaptve"],
    "up value out of range": ["up", "--set", "seed=-1"],
    "up unknown setting": ["up", "--set", "nosuch=1"],
    "up bad rig id": ["up", "--rig-id", "a/b"],
    "up bad duration": ["up", "--duration", "-3"],
    "reconfigure FFT width": ["reconfigure", "--fft-width", "1000"],
    "reconfigure alpha": ["reconfigure", "--alpha", "7"],
    "fault bad channel": ["fault", "short_ground", "AI9"],
    "fault kind of the other side": ["fault", "noise", "AO1", "--sigma-v", "0.1"],
    "fault bad size": ["fault", "offset", "AI3", "--offset-v", "99"],
    "fault bad timeout": ["fault", "open", "AI3", "--timeout", "-1"],
    "plot missing file": ["plot", "{tmp}/missing.mcap"],
    "plot not an MCAP file": ["plot", "{tmp}/not.mcap"],
    "replay a folder": ["replay", "{tmp}"],
    "timing-test missing scenario": ["timing-test", "{tmp}/missing.yaml"],
    "bench bad rate": ["bench", "--rate", "abc"],
    "monitor bad window": ["monitor", "--window", "-1"],
    "credentials bad rig id": ["credentials", "--rig-id", "a/b", "--out", "{tmp}/secrets"],
    "memory-slope bad duration": ["memory-slope", "--duration", "-3"],
    "experiment unknown": ["experiment", "nosuch"],
    "sweep missing spec": ["sweep", "{tmp}/missing.yaml"],
    "sweep spec of another kind": ["sweep", "{tmp}/not.mcap"],
    "unknown command": ["nosuch"],
}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("argv", list(BAD.values()), ids=list(BAD))
def test_bad_argument_is_one_line_and_exit_2(tmp_path: Path, argv: list[str]) -> None:
    (tmp_path / "not.mcap").write_text("not a recording")
    args = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    env = {**os.environ, "COLUMNS": "400"}  # a message is one line; rich wraps it at 80 columns when not on a terminal
    proc = subprocess.run([sys.executable, "-m", "workbench", *args], capture_output=True, text=True, timeout=100, cwd=tmp_path, env=env)
    lines = messages(proc.stderr)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(lines) == 1 and lines[0].startswith("ralf-hil"), proc.stderr
    assert not (tmp_path / "secrets").exists()
