"""Ctrl-C at any moment of the long commands (``ralf-hil sweep``, ``ralf-hil
experiment``, ``ralf-hil replay --can``; SIGINT to the process group, as a
terminal sends it): while the modules load (at once and 1 s after the
entry point's first line), while the Dask cluster starts (3 s after it) and
mid-run (a readiness line seen, then 1 s). The moments count from the first
line of the entry point (the process runs with ``-X importtime``; the first
module loaded after :mod:`service_kit.interrupt` marks it), not from the
start of the interpreter, whose own start-up a loaded host can stretch past
any fixed delay: a SIGINT before the first line gets Python's handling. Each
ends with exit code 130, the line ``ralf-hil: interrupted``, no traceback,
no "failed", and no process of its own left behind (a sweep's Dask worker
processes included, checked by process id). The runs are long (so a
signal always finds them running) and bounded by a hang guard; no timing is
asserted (the stop took 0.01-1.0 s at load ~4 on 2 cores: docs/timing.md)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.rig.process_tree import descendants, left_behind

HANG_GUARD_S = 30.0
MOMENTS = [0.0, 1.0, 3.0, None]
MOMENT_IDS = ["loading", "1s", "3s", "mid-run"]
HANDLER_MODULE = "service_kit.interrupt"  # the entry point's first line installs its SIGINT handler right after importing it
IMPORT_TIME = "import time:"

SWEEP_SPEC = """\
name: interrupted
mode: cosim
base:
  controller.duration_s: 600   # ~8 s of cosim per run: every run is still going when Ctrl-C comes
grid:
  plant.adc_bits: [12, 16, 20]
"""


def interrupt(cmd: list[str], cwd: Path, after_s: float | None, running_line: str) -> tuple[int, str, list[int]]:
    """Start ``cmd``; SIGINT to its group ``after_s`` after the entry point's first line (None: 1 s after
    ``running_line``); its exit code, output (without the import-time lines), and the descendants it had when
    the signal went."""
    proc = subprocess.Popen(
        [sys.executable, "-X", "importtime", "-m", "workbench", *cmd],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
        start_new_session=True,  # a process group of its own, as a shell gives a foreground job
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
    reader.start()
    try:
        wait_for_line(proc, lines, past_the_first_line, "the first line")
        if after_s is None:
            wait_for_line(proc, lines, lambda seen: any(running_line in line for line in seen), repr(running_line))
            time.sleep(1.0)
        else:
            time.sleep(after_s)
        assert proc.poll() is None, f"ended before the signal:\n{''.join(lines)[-3000:]}"
        kids = descendants(proc.pid)
        os.killpg(proc.pid, signal.SIGINT)
        code = proc.wait(timeout=HANG_GUARD_S)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    reader.join(timeout=10)
    return code, "".join(line for line in lines if IMPORT_TIME not in line), kids


def past_the_first_line(lines: list[str]) -> bool:
    """The output shows a module loaded after the handler's module: the entry point runs its first line."""
    marks = [i for i, line in enumerate(lines) if IMPORT_TIME in line and line.rstrip().endswith(HANDLER_MODULE)]
    return bool(marks) and any(IMPORT_TIME in line for line in lines[marks[0] + 1 :])


def wait_for_line(proc: subprocess.Popen[str], lines: list[str], found: Callable[[list[str]], bool], what: str) -> None:
    """Until the output so far satisfies ``found``; fails if the process ends or 180 s pass first."""
    deadline = time.monotonic() + 180
    while not found(list(lines)):
        assert proc.poll() is None, "".join(lines)[-3000:]
        assert time.monotonic() < deadline, f"no {what} after 180 s:\n{''.join(lines)[-3000:]}"
        time.sleep(0.02)


def check_clean_stop(code: int, out: str, kids: list[int]) -> None:
    assert code == 130, out[-3000:]
    assert "ralf-hil: interrupted" in out, out[-3000:]
    assert "Traceback" not in out and "KeyboardInterrupt" not in out, out[-3000:]
    assert "failed" not in out, out[-3000:]
    left = left_behind(kids)
    assert not left, f"processes left behind: {left}\n{out[-3000:]}"


@pytest.mark.timeout(240)
@pytest.mark.parametrize("after_s", MOMENTS, ids=MOMENT_IDS)
def test_ctrl_c_stops_a_sweep_and_its_dask_workers(tmp_path: Path, after_s: float | None) -> None:
    (tmp_path / "spec.yaml").write_text(SWEEP_SPEC)
    cmd = ["sweep", "spec.yaml", "--workers", "2", "--out", "out", "--no-progress"]
    code, out, kids = interrupt(cmd, tmp_path, after_s, "to run on local cluster")
    check_clean_stop(code, out, kids)
    if after_s is None:
        assert len(kids) >= 2, f"no Dask workers were running: {kids}"


@pytest.mark.timeout(240)
@pytest.mark.parametrize("after_s", MOMENTS, ids=MOMENT_IDS)
def test_ctrl_c_stops_an_experiment(tmp_path: Path, after_s: float | None) -> None:
    cmd = ["experiment", "battery", "--quick", "--no-progress", "--workers", "2", "--out", "out"]
    code, out, kids = interrupt(cmd, tmp_path, after_s, "on local cluster")
    check_clean_stop(code, out, kids)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A co-simulated run of 30 simulated seconds, recorded: its CAN side plays for ~30 s."""
    path = tmp_path_factory.mktemp("replay") / "run.mcap"
    done = subprocess.run(
        [sys.executable, "-m", "workbench", "up", "--clock", "cosim", "--duration", "30", "--record", str(path)], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return path


@pytest.mark.timeout(240)
@pytest.mark.parametrize("after_s", MOMENTS, ids=MOMENT_IDS)
def test_ctrl_c_stops_a_can_replay(tmp_path: Path, recording: Path, after_s: float | None) -> None:
    port = 42000 + int.from_bytes(os.urandom(2), "big") % 3000
    cmd = ["replay", str(recording), "--can", "--port", str(port), "--max-wall", "120"]
    code, out, kids = interrupt(cmd, tmp_path, after_s, "CAN frames onto")
    check_clean_stop(code, out, kids)
