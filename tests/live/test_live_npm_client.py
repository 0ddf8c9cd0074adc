"""The live view read by Foxglove's own client: ``@foxglove/ws-protocol`` from the npm
registry (tests/live/node, ``npm ci`` there; .ci/run installs it) under the machine's
Node.js. Skipped where Node.js or the installed package is missing."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from protocol.messages import GroundTruth, encode
from workbench.live.view import SUBPROTOCOL, LiveView
from workbench.recording.reader import Recording
from workbench.recording.recorder import Recorder

NODE_DIR = Path(__file__).parent / "node"
pytestmark = [
    pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed"),
    pytest.mark.skipif(not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir(), reason="run `npm ci` in tests/live/node first"),
    pytest.mark.timeout(120),
]
TOPIC = "ralf/npm/plant/truth"
OFFERED_BY_FOXGLOVE = "foxglove.websocket.v1,foxglove.sdk.v1"
"""What a Foxglove app that speaks the SDK's servers offers: both names."""


def run_node(url: str, topics: str, seconds: float, *protocols: str) -> dict[str, Any]:
    """watch.cjs (its default subprotocol, the package's, unless ``protocols`` are given): what it saw."""
    out = subprocess.run(
        ["node", str(NODE_DIR / "watch.cjs"), url, topics, str(seconds), *([",".join(protocols)] if protocols else [])],
        cwd=NODE_DIR, capture_output=True, text=True, timeout=90, check=True,
    )  # fmt: skip
    got: dict[str, Any] = json.loads(out.stdout)
    return got


def truth(seq: int) -> GroundTruth:
    t = seq / 64
    return GroundTruth(
        seq=seq, sim_time_s=t, modal_frequencies_hz=(4.4 + t, 11.0), damping_ratios=(0.05, 0.04), deflections_in=(0.01 * seq, -0.02),
        theta_rad=(0.1, 0.2), tip_in=(1.0, 2.0), payload_attached=seq % 2 == 0,
    )  # fmt: skip


def test_foxglove_npm_client_decodes_what_the_recording_holds(tmp_path: Path) -> None:
    view = LiveView("127.0.0.1", 0, rate_hz=1000.0)
    recorder = Recorder(tmp_path / "run.mcap", mirror=view)
    wall = 2048.0
    recorder.on_message(TOPIC, encode(truth(0)), wall_time_s=wall)  # the channel exists before the client comes
    node = subprocess.Popen(
        ["node", str(NODE_DIR / "watch.cjs"), view.url, "/" + TOPIC, "6", OFFERED_BY_FOXGLOVE],
        cwd=NODE_DIR, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip

    def feed() -> None:
        deadline = time.monotonic() + 60
        while view.stats.subscriptions == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        for seq in range(1, 31):
            recorder.on_message(TOPIC, encode(truth(seq)), wall_time_s=wall + seq / 64)
            time.sleep(0.01)

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    try:
        out, err = node.communicate(timeout=90)
    finally:
        feeder.join(30)
        recorder.close()
        view.close()
    got = json.loads(out)
    assert got["errors"] == [], err
    assert got["protocol"] in ("foxglove.websocket.v1", "foxglove.sdk.v1")
    assert got["serverInfo"]["capabilities"] == ["time"]
    recorded = {m["seq"]: m for m in Recording.load(tmp_path / "run.mcap").data("plant/truth")}
    messages = [m for m in got["messages"] if m["topic"] == "/" + TOPIC]
    assert [m["payload"]["seq"] for m in messages] == list(range(1, 31))
    for m in messages:
        assert m["payload"] == recorded[m["payload"]["seq"]]
        assert int(m["timestamp"]) == round(m["payload"]["sim_time_s"] * 1e9)
    [channel] = [c for c in got["channels"] if c["topic"] == "/" + TOPIC]
    assert channel["schemaName"] == "ralf.GroundTruth" and channel["encoding"] == "json"
    assert [int(t) for t in got["times"]] == sorted(int(t) for t in got["times"])


def test_the_npm_client_as_configured_by_default_is_refused_with_one_line_naming_the_subprotocol(caplog: pytest.LogCaptureFixture) -> None:
    """``@foxglove/ws-protocol`` offers ``foxglove.websocket.v1`` only (its ``SUPPORTED_SUBPROTOCOL``),
    which foxglove-sdk 0.30 does not accept: HTTP 400 on its side, one line naming the
    subprotocol the view speaks on the rig's side, and a count."""
    view = LiveView("127.0.0.1", 0)
    try:
        with caplog.at_level(logging.WARNING, logger="workbench.live.view"):
            got = run_node(view.url, "*", 2)
    finally:
        stats = view.close()
    assert got["offered"] == ["foxglove.websocket.v1"] and got["httpStatus"] == 400 and got["protocol"] is None
    lines = [r.getMessage() for r in caplog.records if r.name == "workbench.live.view"]
    assert len(lines) == 1 and SUBPROTOCOL in lines[0] and "refused client 127.0.0.1:" in lines[0], lines
    assert stats.handshakes_refused == 1 and stats.clients_seen == 0


def test_the_npm_client_subscribing_on_advertisement_gets_every_rig_channel() -> None:
    """The client subscribes to each channel the moment its advertisement arrives while records
    flow on every topic of a rig: none is refused, each delivers."""
    from workbench.recording.schemas import rig_topics

    from .test_live_view import feed_every_topic

    topics = rig_topics("npm")
    view = LiveView("127.0.0.1", 0, rate_hz=1e6, topics=topics)
    stop = threading.Event()
    feeder = threading.Thread(target=feed_every_topic, args=(view, topics, stop), daemon=True)
    feeder.start()
    try:
        got = run_node(view.url, "*", 4, SUBPROTOCOL)
    finally:
        stop.set()
        feeder.join(10)
        stats = view.close()
    assert got["protocol"] == SUBPROTOCOL and got["errors"] == []
    assert [s for s in got["statuses"] if "Unknown channel" in s["message"]] == []
    assert {c["topic"] for c in got["channels"]} == {m["topic"] for m in got["messages"]} == {t for t, _ in topics}
    assert stats.late_channels == 0 and stats.subscriptions == len(topics)
