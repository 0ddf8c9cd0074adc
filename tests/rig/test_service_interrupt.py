"""Ctrl-C at any moment of a service started on its own (``ralf-plant``,
``ralf-controller``, ``ralf-dsp``; SIGINT to its process group, as a
terminal sends it): while its modules load (0.2 s, 1 s), in its start-up
(3 s) and mid-run (a rig of all three, each stopped once the controller
runs). Each ends with exit code 130, no traceback, and no process of its
own left behind (checked by process id). No timing is asserted (the host
may be loaded): readiness comes from the services' log lines, and the
bounds are hang guards only (the stop takes well under 2 s on an idle
host: docs/timing.md)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.rig.process_tree import descendants, left_behind
from workbench.launcher import free_tcp_ports

HANG_GUARD_S = 20.0
"""The most a stop may take here: far above the 0.01-1.1 s measured, so only a hang fails."""

SERVICES = ("ralf-plant", "ralf-controller", "ralf-dsp")


def service_env(port: int, connect: list[int], rig_id: str, can_port: int) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env.update(
        {
            "RALF_RIG_ID": rig_id,
            "RALF_CAN_PORT": str(can_port),
            "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{port}",
            "RALF_ZENOH_CONNECT": ",".join(f"tcp/127.0.0.1:{p}" for p in connect),
        }
    )
    return env


def start(service: str, env: dict[str, str], log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as out:
        return subprocess.Popen(
            [str(Path(sys.executable).parent / service)],
            env=env,
            stdout=out,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # a process group of its own, as a shell gives a foreground job
        )


def wait_for_line(log: Path, text: str, proc: subprocess.Popen[bytes], timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text(errors="replace"):
        assert proc.poll() is None, f"{log.name} ended before {text!r}:\n{log.read_text(errors='replace')[-3000:]}"
        assert time.monotonic() < deadline, f"no {text!r} in {log.name} after {timeout_s:.0f} s"
        time.sleep(0.1)


def interrupt(proc: subprocess.Popen[bytes], log: Path) -> tuple[int, str]:
    """SIGINT to the process group; the exit code and the log, after checking no child outlives it."""
    kids = descendants(proc.pid)
    os.killpg(proc.pid, signal.SIGINT)
    try:
        code = proc.wait(timeout=HANG_GUARD_S)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        pytest.fail(f"{log.name} still running {HANG_GUARD_S:.0f} s after SIGINT:\n{log.read_text(errors='replace')[-3000:]}")
    left = left_behind(kids)
    assert not left, f"{log.name}: children left behind: {left}"
    return code, log.read_text(errors="replace")


@contextmanager
def killed_at_exit(procs: list[subprocess.Popen[bytes]]) -> Iterator[None]:
    try:
        yield
    finally:
        for proc in procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


@pytest.mark.timeout(120)
@pytest.mark.parametrize("after_s", [0.2, 1.0, 3.0], ids=["0.2s", "1s", "3s"])
@pytest.mark.parametrize("service", SERVICES)
def test_ctrl_c_stops_a_lone_service_while_it_starts(tmp_path: Path, service: str, after_s: float) -> None:
    (port,) = free_tcp_ports(1)
    env = service_env(port, [], f"int-{uuid.uuid4().hex[:8]}", 40000 + uuid.uuid4().int % 20000)
    log = tmp_path / f"{service}.log"
    proc = start(service, env, log)
    with killed_at_exit([proc]):
        time.sleep(after_s)
        code, text = interrupt(proc, log)
    assert code == 130, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    assert "interrupted" in text or "received SIGINT, stopping" in text, text[-3000:]


@pytest.mark.timeout(300)
def test_ctrl_c_stops_each_service_of_a_running_rig(tmp_path: Path) -> None:
    """The README's services one by one, running (the controller ticking); then
    Ctrl-C to each in turn: controller, plant, DSP."""
    ports = free_tcp_ports(3)
    rig_id, can_port = f"int-{uuid.uuid4().hex[:8]}", 40000 + uuid.uuid4().int % 20000
    logs = {s: tmp_path / f"{s}.log" for s in ("ralf-dsp", "ralf-plant", "ralf-controller")}
    procs: list[subprocess.Popen[bytes]] = []
    with killed_at_exit(procs):
        procs.append(start("ralf-dsp", service_env(ports[0], [], rig_id, can_port), logs["ralf-dsp"]))
        procs.append(start("ralf-plant", service_env(ports[1], [ports[0]], rig_id, can_port), logs["ralf-plant"]))
        procs.append(start("ralf-controller", service_env(ports[2], ports[:2], rig_id, can_port), logs["ralf-controller"]))
        dsp, plant, controller = procs
        wait_for_line(logs["ralf-controller"], "ready in", controller)
        time.sleep(1.0)  # control runs
        for proc, name in ((controller, "ralf-controller"), (plant, "ralf-plant"), (dsp, "ralf-dsp")):
            code, text = interrupt(proc, logs[name])
            assert code == 130, f"{name}:\n{text[-3000:]}"
            assert "Traceback" not in text and "received SIGINT, stopping" in text, f"{name}:\n{text[-3000:]}"
    assert "run ended after" in logs["ralf-controller"].read_text()


@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    ("service", "wait_line"),
    [
        ("ralf-controller", "waiting for the plant node 1 on CAN udp_multicast (its boot-up or heartbeat)..."),
        ("ralf-dsp", "on zenoh (its run-start reset or a batch)..."),
    ],
)
def test_a_lone_service_says_what_it_waits_for(tmp_path: Path, service: str, wait_line: str) -> None:
    """A controller without a plant, a DSP without a controller: each names
    what it waits for (once), then stops on Ctrl-C as usual."""
    (port,) = free_tcp_ports(1)
    env = service_env(port, [], f"wait-{uuid.uuid4().hex[:8]}", 40000 + uuid.uuid4().int % 20000)
    log = tmp_path / f"{service}.log"
    proc = start(service, env, log)
    with killed_at_exit([proc]):
        wait_for_line(log, wait_line, proc)
        code, text = interrupt(proc, log)
    assert code == 130, text[-3000:]
    assert text.count(wait_line) == 1, text[-3000:]
    assert " INFO " in next(line for line in text.splitlines() if wait_line in line)
