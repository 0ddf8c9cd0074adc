"""Ctrl-C at any moment of `ralf-hil up` (SIGINT to its process group, as a
terminal sends it): while its modules load, while the services start, and
mid-run. Each ends with exit code 130, one clean line, no traceback, no
"rig failed", and no process of the rig left behind. No timing is asserted
(the machine may be loaded): the bounds are generous timeouts."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest


def rig_processes(rig_id: str) -> list[int]:
    """Processes whose environment names this rig (the services `up` started)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if f"RALF_RIG_ID={rig_id}".encode() in (entry / "environ").read_bytes():
                found.append(int(entry.name))
        except OSError:
            continue
    return found


def _interrupt_up(tmp_path: Path, after_s: float | None) -> tuple[int, str, str, str]:
    """Start `up`, send SIGINT to its process group ``after_s`` seconds in (None:
    once every service is ready); its exit code, stdout, stderr and the rig id."""
    rig_id = f"int-{uuid.uuid4().hex[:8]}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "workbench", "up", "--duration", "120", "--rig-id", rig_id, "--log-dir", str(tmp_path / "logs")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # a process group of its own, as a shell gives a foreground job
    )
    try:
        if after_s is None:
            assert proc.stderr is not None
            seen = ""
            while "all services ready" not in seen:
                line = proc.stderr.readline()
                assert line, f"up ended before the rig was ready: {seen}"
                seen += line
            time.sleep(1.0)
        else:
            time.sleep(after_s)
        os.killpg(proc.pid, signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode, out, err, rig_id


@pytest.mark.timeout(300)
@pytest.mark.parametrize("after_s", [0.2, 1.0, 3.0, None], ids=["0.2s", "1s", "3s", "mid-run"])
def test_ctrl_c_stops_up_and_every_service(tmp_path: Path, after_s: float | None) -> None:
    code, out, err, rig_id = _interrupt_up(tmp_path, after_s)
    assert code == 130, out + err
    assert "Traceback" not in err and "rig failed" not in err, err
    assert "interrupted" in err
    for _ in range(50):  # the services got SIGTERM (or SIGKILL) before up returned; /proc may lag a moment
        left = rig_processes(rig_id)
        if not left:
            break
        time.sleep(0.1)
    assert not left, f"processes of rig {rig_id} left behind: {left}"


@pytest.mark.timeout(60)
def test_a_burst_of_signals_never_deadlocks_the_stop_event() -> None:
    """Many SIGTERMs while the main thread sits in ``stop.wait()`` (which holds
    the event's lock for a moment on every call): the handler takes no lock,
    so the event is set and the signals are named."""
    from service_kit.runtime import stop_on_signals

    previous = signal.getsignal(signal.SIGTERM)
    try:
        stop, received = stop_on_signals((signal.SIGTERM,), say=False)
        for _ in range(200):
            os.kill(os.getpid(), signal.SIGTERM)
            stop.wait(1e-5)
        assert stop.wait(30.0)
        # Signals arriving before Python runs the handler are one call (CPython coalesces them).
        assert 1 <= len(received) <= 200 and set(received) == {"SIGTERM"}
    finally:
        signal.signal(signal.SIGTERM, previous)
