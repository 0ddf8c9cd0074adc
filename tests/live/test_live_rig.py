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
    cmd = [sys.executable, "-m", "workbench", "up", "--clock", "lockstep", "--duration", "40", "--rig-id", RIG,
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
    # subscribed the moment each channel was advertised: none refused, the late-starting topics deliver too
    assert [s["message"] for s in got.statuses if "Unknown channel" in s["message"]] == []
    delivered = {topic for topic, _, _ in got.messages}
    assert {"/can", f"/ralf/{RIG}/dsp/interrupt", *(f"/ralf/{RIG}/health/{s}" for s in ("dsp", "plant", "controller"))} <= delivered
    assert summary["live"]["late_channels"] == 0


def test_ralf_hil_live_joins_a_rig_started_elsewhere(tmp_path: Path) -> None:
    """``ralf-hil live`` beside a rig it did not start (here ``ralf-hil up``'s, as ``docker compose``'s
    would be): it joins with the tool role's credentials, taps zenoh and CAN, and serves them. The
    rig runs until the client has seen both topics (a loaded host may take many seconds to start
    ``live``), then is stopped as Ctrl-C stops it."""
    import os
    import re
    import signal
    import time

    live_port = free_tcp_ports(1)[0]
    up = subprocess.Popen(
        [sys.executable, "-m", "workbench", "up", "--clock", "realtime", "--duration", "300", "--rig-id", "livejoin", "--log-dir", str(tmp_path)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "COLUMNS": "400"},  # one line per message: rich wraps at the terminal's width
    )  # fmt: skip
    live = None
    try:
        assert up.stdout is not None
        m = t = None
        for line in up.stdout:  # the rig's ports, and the run's own owner-only credentials folder
            m = m or re.search(r"CAN udp_multicast port (\d+), zenoh (tls/127\.0\.0\.1:\d+)", line)
            t = t or re.search(r"tools' credentials in (\S+)", line)
            if m and t:
                break
        assert m and t, (m, t)
        tool_env = Path(t.group(1))
        deadline = time.monotonic() + 60
        while not tool_env.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        env = {**os.environ, **dict(row.split("=", 1) for row in tool_env.read_text().splitlines() if "=" in row)}
        live = subprocess.Popen(
            [sys.executable, "-m", "workbench", "live", f"127.0.0.1:{live_port}", "--connect", m.group(2), "--can-port", m.group(1), "--duration", "120"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        got = asyncio.run(watch(f"ws://127.0.0.1:{live_port}", {"/ralf/livejoin/plant/truth", "/can/decoded/TPDO1_AnalogInputs16"}, 90.0, until_topic_count=2))
    finally:
        if up.poll() is None:
            up.send_signal(signal.SIGINT)  # the rig has served its purpose
        up.communicate(timeout=120)  # drained: the rest of its output never fills the pipe
        if live is not None:
            live.terminate()
            out, err = live.communicate(timeout=30)
    assert {t for t, _, _ in got.messages} == {"/ralf/livejoin/plant/truth", "/can/decoded/TPDO1_AnalogInputs16"}, err[-2000:]
    assert json.loads(out.strip().splitlines()[-1])["clients_seen"] == 1


def test_ralf_hil_live_port_in_use_is_one_line() -> None:
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        res = subprocess.run([sys.executable, "-m", "workbench", "live", str(port), "--duration", "1"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "Address already in use" in res.stderr, res.stderr


async def _slow_client(url: str, seconds: float, read_every_s: float = 0.2, fast_s: float = 5.0) -> int:
    """A client on the plain ``websockets`` library that subscribes to every channel and then reads
    one frame every ``read_every_s`` after its first ``fast_s``: its socket's receive buffer is 4 KiB and the library holds at
    most one unread frame, so the server's TCP send stalls within a second. Frames read."""
    import socket
    import time

    import websockets

    deadline = time.monotonic() + 60
    while True:
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            sock.connect(("127.0.0.1", int(url.rsplit(":", 1)[1])))
            break
        except OSError:
            sock.close()
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    ws = await websockets.connect(url, sock=sock, subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"], max_size=None, max_queue=1)  # type: ignore[list-item]
    read, subscribed = 0, False
    end = time.monotonic() + seconds
    slow_from = time.monotonic() + fast_s  # until then it reads at full speed: every advertisement, every subscription
    try:
        async with ws:
            while time.monotonic() < end:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.01, end - time.monotonic()))
                read += isinstance(frame, bytes) and frame[:1] == b"\x01"  # Message Data (opcode 1): not time or status frames
                if isinstance(frame, str) and json.loads(frame).get("op") == "advertise":
                    channels = json.loads(frame)["channels"]
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in channels]}))
                    subscribed = True
                elif subscribed and time.monotonic() > slow_from:
                    await asyncio.sleep(read_every_s)
    except (TimeoutError, websockets.ConnectionClosed):  # the run ended and its server with it
        pass
    return read


def test_a_slow_client_leaves_the_rig_alone(tmp_path: Path) -> None:
    """A lockstep run served live (1000 messages a second per topic) to a client that reads one
    frame a second after its first five seconds: the run ends as it would without a client (every
    tick, no deadline miss, exit 0), the view's counters move, nothing is dropped on the way to the
    view. (This run's whole stream, about 1 MB, fits the kernel's socket buffers: the SDK's own
    drops are shown by ``test_live_view.py::test_a_slow_client_is_noticed``.)"""
    port = free_tcp_ports(1)[0]
    duration = 20.0
    cmd = [sys.executable, "-m", "workbench", "up", "--clock", "lockstep", "--duration", str(duration), "--rig-id", "liveslow",
           "--live", f"127.0.0.1:{port}", "--live-rate", "1000", "--json", str(tmp_path / "summary.json")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        read = asyncio.run(_slow_client(f"ws://127.0.0.1:{port}", 150.0, read_every_s=1.0))
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-2000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    live, controller = summary["live"], summary["controller"]
    assert live["clients_seen"] == 1 and live["published"] >= read > 0 and live["decimated"] > 0 and live["handoff_dropped"] == 0, (live, read)
    assert controller["ticks"] >= round(duration * 200) and controller["deadline_misses"] == 0, controller
