"""``ralf-hil record`` beside a service started on its own: the plant alone
(listening on zenoh, heartbeats on udp_multicast inside the loopback
namespace) is recorded with its health, liveliness and CAN frames."""

from __future__ import annotations

import os
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from workbench.launcher import free_tcp_port, terminate
from workbench.recording.reader import Recording


@pytest.mark.timeout(120)
def test_record_a_plant_running_alone(tmp_path: Path) -> None:
    rig_id = f"alone-{uuid.uuid4().hex[:6]}"
    zport, can_port = free_tcp_port(), 45000 + os.getpid() % 5000
    env = {
        **os.environ,
        "RALF_RIG_ID": rig_id,
        "RALF_CAN_PORT": str(can_port),
        "RALF_SEED": "5",
        "RALF_HEALTH_PERIOD_S": "0.5",
        "PYTHONUNBUFFERED": "1",
    }
    plant = subprocess.Popen(
        [sys.executable, "-m", "plant_emulator"],
        env={**env, "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{zport}"},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.STDOUT,
    )
    try:
        time.sleep(1.0)
        path = tmp_path / "plant.mcap"
        proc = subprocess.run(
            [sys.executable, "-m", "workbench", "record", str(path), "--connect", f"tcp/127.0.0.1:{zport}", "--duration", "4"],
            env=env, capture_output=True, text=True, timeout=60,
        )  # fmt: skip
        assert proc.returncode == 0, proc.stderr
    finally:
        assert terminate(plant) == 0
    rec = Recording.load(path)
    assert rec.rig_id == rig_id
    frames = rec.can_frames()
    assert frames and {f["frame"] for f in frames} == {"heartbeat"}  # no master: only its heartbeat (pre-operational)
    assert {f["direction"] for f in frames} == {"plant->controller"}
    assert all(f["sim_time_s"] is None for f in frames)  # no SYNC yet: no simulated time
    assert len(rec.data("health/plant")) >= 2
    assert any(m.data["service"] == "plant" and m.data["alive"] for m in rec.iter("alive"))
    assert rec.settings("plant")["seed"] == 5  # the recorder's RALF_* environment, as the plant read it


@pytest.mark.timeout(120)
def test_a_service_records_itself_with_record_flag(tmp_path: Path) -> None:
    """``ralf-dsp --record RUN.mcap``: a recorder child beside the board, with the board's --set settings."""
    rig_id = f"self-{uuid.uuid4().hex[:6]}"
    path = tmp_path / "dsp.mcap"
    env = {**os.environ, "RALF_RIG_ID": rig_id, "RALF_HEALTH_PERIOD_S": "0.5", "RALF_CAN_PORT": str(45000 + (os.getpid() + 7) % 5000), "PYTHONUNBUFFERED": "1"}
    dsp = subprocess.Popen(
        [sys.executable, "-m", "dsp_service", "--set", "fft_width=1024", "--record", str(path), "--set", f"zenoh_listen=tcp/127.0.0.1:{free_tcp_port()}"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (path.exists() and path.stat().st_size > 0):
            time.sleep(0.2)
        time.sleep(4.0)  # the empty-block flag every 0.5 s, health every 0.5 s
    finally:
        assert terminate(dsp) == 0
    rec = Recording.load(path)
    assert rec.rig_id == rig_id
    flags = rec.data("dsp/flag")
    assert flags and {f["fft_width"] for f in flags} == {1024} and {f["state"] for f in flags} == {"empty"}
    assert rec.data("health/dsp")
    assert rec.settings("dsp")["fft_width"] == 1024  # the --set override reached the recorder's metadata
