"""``ralf-hil up --live`` on a running three-process rig (lockstep, udp_multicast CAN: run in
the loopback-only namespace), watched by the spec-written client and compared with the same
run's recording."""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from workbench.launcher import free_tcp_ports
from workbench.recording.foxglove import message_paths
from workbench.recording.reader import Recording

from .ws_client import watch

pytestmark = [pytest.mark.rig, pytest.mark.slow, pytest.mark.timeout(240)]
RIG = "livetest"


def test_live_view_of_a_running_rig_matches_its_recording(tmp_path: Path) -> None:
    port = free_tcp_ports(1)[0]
    cmd = [sys.executable, "-m", "workbench", "up", "--clock", "lockstep", "--duration", "6", "--rig-id", RIG,
           "--live", f"127.0.0.1:{port}", "--live-rate", "50", "--record", str(tmp_path / "run.mcap"), "--json", str(tmp_path / "summary.json")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        got = asyncio.run(watch(f"ws://127.0.0.1:{port}", None, 200.0, connect_timeout_s=60.0))
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["live"]["clients_seen"] == 1 and summary["live"]["published"] > 0
    rec = Recording.load(tmp_path / "run.mcap", only=("plant/truth", "dsp/interrupt", "health/controller", "controller/status"))
    recorded_truth = {m["seq"]: m for m in rec.data("plant/truth")}
    recorded_irq = {m["seq"]: m for m in rec.data("dsp/interrupt")}
    live_truth = [m for topic, _, m in got.messages if topic == f"/ralf/{RIG}/plant/truth"]
    live_irq = [m for topic, _, m in got.messages if topic == f"/ralf/{RIG}/dsp/interrupt"]
    assert len(live_truth) > 20 and len(live_irq) > 5
    assert all(m == recorded_truth[m["seq"]] for m in live_truth)
    assert all(m == recorded_irq[m["seq"]] for m in live_irq)
    # every message's timestamp and the server's time are the simulated time
    for topic, ts, m in got.messages:
        if topic.startswith(f"/ralf/{RIG}/plant/truth"):
            assert ts == round(m["sim_time_s"] * 1e9)
    assert got.times == sorted(got.times) and got.times[-1] >= round(live_truth[-1]["sim_time_s"] * 1e9)
    # the shipped layout's plots find their topics live as in the recording
    live_topics = {c["topic"] for c in got.channels.values()}
    with open(tmp_path / "run.mcap", "rb") as fh:
        summary_ = make_reader(fh).get_summary()
    assert summary_ is not None
    recorded_topics = {c.topic for c in summary_.channels.values()}
    for path in message_paths(RIG):
        topic = path.split(".", 1)[0]
        assert topic in live_topics and topic in recorded_topics, path
    assert {c["topic"] for c in got.channels.values()} >= {"/can", "/can/decoded/SYNC", f"/ralf/{RIG}/controller/tf", f"/ralf/{RIG}/health/controller"}
