"""``ralf-hil monitor``: a zenoh peer in the test plays a service (health,
liveliness token, controller status) on a private rig id; the monitor's
snapshot and rendering must show what it published."""

from __future__ import annotations

import io
import json
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import zenoh
from rich.console import Console

from protocol.errors import ConfigError
from protocol.keys import Keys
from protocol.messages import ControllerStatus, Health, LatencyStats, encode
from workbench import monitor
from workbench.launcher import free_tcp_port


@dataclass
class FakeService:
    rig_id: str
    endpoint: str
    session: zenoh.Session
    token: zenoh.LivelinessToken | None


@pytest.fixture(autouse=True)
def _clean_ralf_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for name in list(os.environ):
        if name.startswith("RALF_"):
            monkeypatch.delenv(name)


@pytest.fixture
def service() -> Iterator[FakeService]:
    rig_id = f"mon-{uuid.uuid4().hex[:8]}"
    port = free_tcp_port()
    keys = Keys(rig_id)
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    session = zenoh.open(config)
    stop = threading.Event()
    fake = FakeService(rig_id, f"tcp/127.0.0.1:{port}", session, session.liveliness().declare_token(keys.alive("plant")))
    health_pub = session.declare_publisher(keys.health("plant"))
    status_pub = session.declare_publisher(keys.controller_status)

    def publish() -> None:
        seq = 0
        while not stop.is_set():
            health = Health(
                seq=seq,
                sim_time_s=1.25,
                service="plant",
                state="degraded",
                counters={"syncs_applied": 250, "tx_errors": 0},
                latencies={"sync_to_tpdo": LatencyStats(count=250, p50=0.0002, p99=0.0004, p999=0.0009, max=0.0012)},
                last_miss="valves held: SYNC watchdog",
            )
            health_pub.put(encode(health))
            status_pub.put(
                encode(ControllerStatus(seq=seq, sim_time_s=1.25, ticks=250, loop_rate_hz=199.5, batches_sent=12, interrupts=11, latest_frequency_hz=4.4))
            )
            seq += 1
            stop.wait(0.1)

    thread = threading.Thread(target=publish, daemon=True)
    thread.start()
    try:
        yield fake
    finally:
        stop.set()
        thread.join(timeout=5)
        if fake.token is not None:
            fake.token.undeclare()
        health_pub.undeclare()
        status_pub.undeclare()
        session.close()


@pytest.mark.timeout(60)
def test_once_snapshot_shows_health_liveliness_and_status(service: FakeService) -> None:
    snap = monitor.snapshot_once(service.rig_id, connect=service.endpoint, window_s=1.5)
    plant = snap["services"]["plant"]
    assert plant["alive"] == "up"
    assert plant["health"]["state"] == "degraded"
    assert plant["health"]["counters"]["syncs_applied"] == 250
    assert plant["health"]["latencies"]["sync_to_tpdo"]["count"] == 250
    assert plant["health"]["last_miss"] == "valves held: SYNC watchdog"
    assert plant["health_age_s"] is not None and plant["health_age_s"] >= 0
    assert snap["services"]["dsp"]["alive"] == "unknown" and snap["services"]["dsp"]["health"] is None
    assert snap["controller"]["ticks"] == 250
    json.dumps(snap)  # JSON-ready

    buf = io.StringIO()
    Console(file=buf, width=220).print(monitor.render(snap))
    text = buf.getvalue()
    assert service.rig_id in text
    assert "plant" in text and "up" in text and "degraded" in text
    assert "syncs_applied=250" in text and "(1 more at 0)" in text
    assert "sync_to_tpdo" in text and "0.200" in text  # p50 in ms
    assert "valves held: SYNC watchdog" in text
    assert "loop 199.5 Hz" in text and "f1 4.400 Hz" in text
    assert "no health yet" in text  # dsp and controller never sent one


@pytest.mark.timeout(60)
def test_lost_liveliness_is_shown(service: FakeService) -> None:
    settings = monitor.monitor_settings(service.rig_id, service.endpoint)
    with monitor.open_watch(settings) as watch:
        deadline = time.monotonic() + 10
        while watch.snapshot()["services"]["plant"]["alive"] != "up" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert service.token is not None
        service.token.undeclare()
        service.token = None
        while watch.snapshot()["services"]["plant"]["alive"] != "lost" and time.monotonic() < deadline:
            time.sleep(0.05)
        snap = watch.snapshot()
    assert snap["services"]["plant"]["alive"] == "lost"
    assert [e["event"] for e in snap["events"] if e["service"] == "plant"] == ["up", "lost"]


@pytest.mark.timeout(60)
def test_cli_once_json(service: FakeService, capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    code = main(["monitor", "--once", "--rig-id", service.rig_id, "--connect", f"{service.endpoint}, ", "--window", "1.5", "--json"])
    out = capsys.readouterr().out
    assert code == 0
    snap = json.loads(out)
    assert snap["rig_id"] == service.rig_id and snap["services"]["plant"]["alive"] == "up"


def test_env_settings_are_honoured(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("RALF_RIG_ID", "from-env")
    monkeypatch.setenv("RALF_ZENOH_CONNECT", "tcp/127.0.0.1:7447,tcp/127.0.0.1:7448")
    s = monitor.monitor_settings()
    assert s.rig_id == "from-env" and s.endpoints("connect") == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448"]
    s = monitor.monitor_settings("cli-rig", "tcp/127.0.0.1:9000")
    assert s.rig_id == "cli-rig" and s.endpoints("connect") == ["tcp/127.0.0.1:9000"]


def test_no_endpoint_is_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ConfigError, match="--connect"):
        monitor.monitor_settings("x")
    from workbench.cli import main

    assert main(["monitor", "--once", "--rig-id", "x"]) == 2
    assert "--connect" in capsys.readouterr().err
    assert main(["monitor", "--once", "--rig-id", "bad/id", "--connect", "tcp/127.0.0.1:1"]) == 2


def test_nothing_heard_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    # a rig id nobody uses, on a port nobody listens on: the peer keeps retrying, hears nothing
    code = main(["monitor", "--once", "--rig-id", f"none-{uuid.uuid4().hex[:6]}", "--connect", f"tcp/127.0.0.1:{free_tcp_port()}", "--window", "0.5"])
    assert code == 1
    assert "nothing heard" in capsys.readouterr().err
