"""The README's "services one by one" example, run as written (its three
commands in bash, on free ports instead of 7450-7452, a CAN port of its own,
and in lockstep so that no warning depends on the host's load): the rig runs,
every service exits 0 and no log line is an ERROR or a WARNING (a peer that
connects to itself, or two peers that connect to each other, log refused
links every few seconds)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from workbench.launcher import free_tcp_ports

ROOT = Path(__file__).resolve().parents[2]


def readme_block() -> str:
    text = (ROOT / "README.md").read_text()
    section = text.split("### Running the services one by one", 1)[1]
    match = re.search(r"```bash\n(.*?)```", section, re.DOTALL)
    assert match, "the README's services-one-by-one block is missing"
    return match.group(1)


@pytest.mark.timeout(180)
def test_the_readme_services_one_by_one_run_clean(tmp_path: Path) -> None:
    block = readme_block()
    ports = free_tcp_ports(3)
    script = re.sub(r"127\.0\.0\.1:745([0-2])", lambda m: f"127.0.0.1:{ports[int(m.group(1))]}", block)
    assert script != block, "the block no longer uses ports 7450-7452"
    # The controller runs in the foreground and stops after RALF_DURATION_S; the others are then stopped
    # as a script stops its background jobs (SIGTERM: exit 0; a Ctrl-C, SIGINT, would end them with 130).
    wrapper = script + '\nrc=$?\npids=$(jobs -p)\nkill -TERM $pids\nfor p in $pids; do wait "$p" || rc=$((rc + 100)); done\nexit $rc\n'
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env.update(
        {
            "PATH": f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
            "RALF_RIG_ID": f"readme-{uuid.uuid4().hex[:6]}",
            "RALF_CAN_PORT": str(40000 + uuid.uuid4().int % 20000),
            "RALF_DURATION_S": "8",
            "RALF_CLOCK": "lockstep",
        }
    )
    done = subprocess.run(["bash", "-c", wrapper], env=env, cwd=tmp_path, capture_output=True, text=True, timeout=170)
    log = re.sub(r"\x1b\[[0-9;]*m", "", done.stdout + done.stderr)  # zenoh's own log lines come coloured
    assert done.returncode == 0, log[-4000:]
    assert "run ended after 1600 ticks" in log, log[-4000:]
    noisy = [line for line in log.splitlines() if re.search(r"\b(ERROR|WARNING|WARN)\b", line)]
    assert not noisy, "\n".join(noisy[:20])
