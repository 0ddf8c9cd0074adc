"""The live view read by Foxglove's own client: ``@foxglove/ws-protocol`` from the npm
registry (tests/live/node, ``npm ci`` there; .ci/run installs it) under the machine's
Node.js. Skipped where Node.js or the installed package is missing."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import time
from pathlib import Path

import pytest

from protocol.messages import GroundTruth, encode
from workbench.live.view import LiveView
from workbench.recording.reader import Recording
from workbench.recording.recorder import Recorder

NODE_DIR = Path(__file__).parent / "node"
pytestmark = [
    pytest.mark.skipif(shutil.which("node") is None, reason="Node.js is not installed"),
    pytest.mark.skipif(not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir(), reason="run `npm ci` in tests/live/node first"),
    pytest.mark.timeout(120),
]
TOPIC = "ralf/npm/plant/truth"


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
        ["node", str(NODE_DIR / "watch.cjs"), view.url, "/" + TOPIC, "6"], cwd=NODE_DIR, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )

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
