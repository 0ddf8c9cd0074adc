"""The live view (workbench/live/view.py) against a client written from the
protocol's specification on plain ``websockets`` (tests/live/ws_client.py)."""

from __future__ import annotations

import asyncio
import json
import logging
import re
import socket
import threading
import time
from typing import Any

import pytest
import websockets

from protocol.messages import ControllerStatus, GroundTruth, Health, PlantEvent, encode
from workbench.cli import main
from workbench.live.view import LiveView, LiveViewError, parse_address
from workbench.recording.recorder import Recorder

from .ws_client import Session, watch

pytestmark = pytest.mark.timeout(120)
RIG = "ralf/lv"


class StepClock:
    """The tap's wall time, moved by hand: decimation without timing."""

    def __init__(self) -> None:
        self.t = 1024.0  # and steps of powers of two: exact sums


def truth(seq: int) -> GroundTruth:
    t = seq * 0.05
    return GroundTruth(
        seq=seq, sim_time_s=t, modal_frequencies_hz=(4.4 + t, 11.0), damping_ratios=(0.05, 0.04), deflections_in=(0.01 * seq, -0.02),
        theta_rad=(0.1, 0.2), tip_in=(1.0, 2.0), payload_attached=False,
    )  # fmt: skip


def run_with_client(view: LiveView, feed: Any, seconds: float = 4.0, topics: set[str] | None = None) -> Session:
    """A client watching ``view`` while ``feed()`` runs in another thread (once the client has subscribed)."""
    started = threading.Event()

    def go() -> None:
        deadline = time.monotonic() + 30
        while view.stats.subscriptions == 0 and time.monotonic() < deadline:
            time.sleep(0.02)
        started.set()
        feed()

    def prime() -> None:  # the channels exist once a record is in: one before the client comes
        feed_first()

    feed_first = getattr(feed, "first", lambda: None)
    prime()
    deadline = time.monotonic() + 30
    while view.stats.records == 0 and time.monotonic() < deadline:  # through the recorder's thread: the channel is advertised
        time.sleep(0.01)
    threading.Thread(target=go, daemon=True).start()
    return asyncio.run(watch(view.url, topics, seconds))


def test_recording_and_live_view_carry_the_same_topics_schemas_and_payloads(tmp_path: Any) -> None:
    """One recorder writes the MCAP file and feeds the view: the client sees the recording's topic,
    schema name and schema, each payload byte for byte, stamped with its simulated time, and the
    server's time is the simulated time."""
    from workbench.recording.reader import Recording

    clock = StepClock()
    view = LiveView("127.0.0.1", 0, rate_hz=1000.0)
    recorder = Recorder(tmp_path / "run.mcap", mirror=view)
    sent: list[GroundTruth] = []

    def first() -> None:
        recorder.on_message(f"{RIG}/plant/truth", encode(truth(0)), wall_time_s=clock.t)

    def feed() -> None:
        for seq in range(1, 40):
            clock.t += 1 / 64
            sent.append(truth(seq))
            recorder.on_message(f"{RIG}/plant/truth", encode(sent[-1]), wall_time_s=clock.t)
            time.sleep(0.005)

    feed.first = first  # type: ignore[attr-defined]
    try:
        got = run_with_client(view, feed, seconds=3.0)
    finally:
        recorder.close()
        view.close()
    rec = Recording.load(tmp_path / "run.mcap")
    recorded = {m["seq"]: m for m in rec.data("plant/truth")}
    live = [(topic, ts, msg) for topic, ts, msg in got.messages if topic == f"/{RIG}/plant/truth"]
    assert len(live) >= 30
    for _topic, ts, msg in live:
        assert msg == recorded[msg["seq"]]  # the run record's values
        assert ts == round(msg["sim_time_s"] * 1e9)
    [channel] = [c for c in got.channels.values() if c["topic"] == f"/{RIG}/plant/truth"]
    from mcap.reader import make_reader

    with open(tmp_path / "run.mcap", "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    [mc] = [c for c in summary.channels.values() if c.topic == channel["topic"]]
    schema = summary.schemas[mc.schema_id]
    assert (channel["schemaName"], channel["encoding"], channel["schemaEncoding"]) == (schema.name, mc.message_encoding, schema.encoding)
    assert json.loads(channel["schema"]) == json.loads(schema.data)
    assert got.server_info["capabilities"] == ["time"]
    assert got.times == sorted(got.times) and got.times[-1] == round(sent[-1].sim_time_s * 1e9)


def test_decimation_and_statuses_are_counted() -> None:
    clock = StepClock()
    view = LiveView("127.0.0.1", 0, rate_hz=8.0)
    recorder = Recorder(None, mirror=view)
    status = ControllerStatus(seq=0, sim_time_s=1.0, ticks=200, loop_rate_hz=200.0, batches_sent=6, interrupts=6, deadline_misses=0)

    def first() -> None:
        recorder.on_message(f"{RIG}/controller/status", encode(status), wall_time_s=clock.t)

    def feed() -> None:
        for seq in range(1, 101):  # 100 records 1/256 s apart: 8 Hz keeps one in 32
            clock.t += 1 / 256
            recorder.on_message(f"{RIG}/plant/truth", encode(truth(seq)), wall_time_s=clock.t)
        clock.t += 1.0
        recorder.on_message(
            f"{RIG}/controller/status", encode(status.model_copy(update={"seq": 1, "sim_time_s": 2.0, "deadline_misses": 3})), wall_time_s=clock.t
        )
        recorder.on_message(
            f"{RIG}/health/controller",
            encode(
                Health(
                    seq=0, sim_time_s=2.0, service="controller", state="degraded", counters={}, latencies={}, last_miss="batch 7: no interrupt within 150 ms"
                )
            ),
            wall_time_s=clock.t,
        )
        recorder.on_message(
            f"{RIG}/plant/events", encode(PlantEvent(seq=0, sim_time_s=2.1, kind="hard_stop", detail="1 joint hard stop(s)")), wall_time_s=clock.t
        )

    feed.first = first  # type: ignore[attr-defined]
    try:
        got = run_with_client(view, feed, seconds=3.0)
    finally:
        recorder.close()
        view.close()
    assert (view.stats.records, view.stats.decimated, view.stats.published) == (104, 96, 8)
    texts = [s["message"] for s in got.statuses]
    assert any(t.startswith("deadline: 3 miss(es) so far (+3) at 2.00 s") for t in texts)
    assert "deadline: batch 7: no interrupt within 150 ms" in texts
    assert any(t.startswith("plant hard_stop at 2.10 s") for t in texts)


def test_a_port_in_use_is_one_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        with pytest.raises(LiveViewError, match=f"cannot serve the live view on 127.0.0.1:{port}: Failed to bind port: Address already in use"):
            LiveView("127.0.0.1", port)
        assert main(["up", "--clock", "lockstep", "--rig-id", "lvport", "--duration", "1", "--live", str(port)]) == 2
    err = capsys.readouterr().err
    assert re.fullmatch(r"ralf-hil up: cannot serve the live view on 127\.0\.0\.1:\d+: .*Address already in use[^\n]*\n", err), err


@pytest.mark.parametrize(
    ("text", "expected"),
    [("8765", ("127.0.0.1", 8765)), ("0.0.0.0:9000", ("0.0.0.0", 9000)), ("[::1]:9001", ("::1", 9001)), ("localhost:1", ("localhost", 1))],
)
def test_addresses(text: str, expected: tuple[str, int]) -> None:
    assert parse_address(text) == expected


@pytest.mark.parametrize("text", ["http", "example.com:80", "70000", "host:"])
def test_bad_addresses(text: str) -> None:
    with pytest.raises(LiveViewError, match="--live"):
        parse_address(text)


def test_live_on_cosim_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["up", "--clock", "cosim", "--duration", "1", "--live", "0"]) == 2
    err = capsys.readouterr().err
    assert "--live serves a running rig" in err and err.count("\n") == 1, err


def test_a_client_of_another_protocol_is_refused_and_the_view_goes_on() -> None:
    """A WebSocket client asking for another subprotocol, and a plain HTTP request, are refused;
    a Foxglove client connected beside them still gets every message."""
    outcomes: list[Any] = []
    clock = StepClock()
    view = LiveView("127.0.0.1", 0, rate_hz=1000.0)
    recorder = Recorder(None, mirror=view)

    async def foreign() -> str:
        try:
            async with websockets.connect(view.url, subprotocols=["mqtt"]):  # type: ignore[list-item]
                return "accepted"
        except websockets.InvalidStatus as exc:
            return f"refused {exc.response.status_code}"

    def http_get() -> bytes:
        with socket.create_connection(("127.0.0.1", view.port), timeout=10) as s:
            s.sendall(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n")
            return s.recv(200)  # the server closes it without a response: no upgrade, no data

    def first() -> None:
        recorder.on_message(f"{RIG}/plant/truth", encode(truth(0)), wall_time_s=clock.t)

    def feed() -> None:
        outcomes.append(asyncio.run(foreign()))
        outcomes.append(http_get()[:12])
        for seq in range(1, 21):
            clock.t += 1 / 64
            recorder.on_message(f"{RIG}/plant/truth", encode(truth(seq)), wall_time_s=clock.t)
            time.sleep(0.005)

    feed.first = first  # type: ignore[attr-defined]
    try:
        got = run_with_client(view, feed, seconds=3.0)
    finally:
        recorder.close()
        view.close()
    assert outcomes[0] == "refused 400" and not outcomes[1].startswith(b"HTTP/1.1 101")
    assert [m[2]["seq"] for m in got.messages if m[2]["seq"] > 0] == list(range(1, 21))


def test_a_stuck_client_never_holds_the_view() -> None:
    """A client that subscribes and then reads nothing while 5000 records of 2 kB go through the
    view's mirror API: every one is handed on without waiting (the SDK keeps at most the backlog
    for that client and drops its oldest), and a second client still receives the newest."""
    view = LiveView("127.0.0.1", 0, rate_hz=1e6, backlog=16)
    schema = {"title": "ralf.Probe", "type": "object"}
    topic = "/ralf/lv/probe"

    def record(seq: int, pad: int = 2000) -> None:
        wall = 1024.0 + seq / 1024
        if view.accept(topic, wall):
            view.on_record(topic, "ralf.Probe", schema, json.dumps({"seq": seq, "sim_time_s": seq / 1024, "pad": "x" * pad}).encode(), wall)

    record(0)

    async def stuck_then_fresh() -> Session:
        ws = await websockets.connect(view.url, subprotocols=["foxglove.sdk.v1"], max_size=None, close_timeout=1)  # type: ignore[list-item]
        assert json.loads(await ws.recv())["op"] == "serverInfo"
        channel = None
        while channel is None:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 30))
            if msg["op"] == "advertise":
                channel = msg["channels"][0]["id"]
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 0, "channelId": channel}]}))
        deadline = time.monotonic() + 30
        while view.stats.subscriptions == 0 and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        for seq in range(1, 5001):  # this client now reads nothing
            record(seq)
        fresh = asyncio.create_task(watch(view.url, None, 3.0))
        await asyncio.sleep(1.0)
        for seq in range(5001, 5011):
            record(seq, pad=0)
            await asyncio.sleep(0.01)
        got = await fresh
        await ws.close()
        return got

    try:
        got = asyncio.run(stuck_then_fresh())
    finally:
        view.close()
    assert view.stats.published == 5011 and view.stats.decimated == 0
    assert {m[2]["seq"] for m in got.messages} >= set(range(5003, 5011))


SLOW_CLIENT_RUN = """
import asyncio, json, socket, sys
import websockets
from workbench.live.view import LiveView

view = LiveView("127.0.0.1", 0, rate_hz=1e6, backlog=16)
schema = {"title": "ralf.Probe", "type": "object"}

def record(seq):
    wall = 1024.0 + seq / 1024
    if view.accept("/ralf/lv/probe", wall):
        view.on_record("/ralf/lv/probe", "ralf.Probe", schema, json.dumps({"seq": seq, "sim_time_s": seq / 1024, "pad": "x" * 2000}).encode(), wall)

async def slow_client():
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(("127.0.0.1", view.port))
    ws = await websockets.connect(view.url, sock=sock, subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"], max_size=None, max_queue=1)
    read, closed, subscribing = 0, False, sys.argv[1] == "subscribed"
    while subscribing:
        msg = json.loads(await asyncio.wait_for(ws.recv(), 30))
        if msg["op"] == "advertise":
            await ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 0, "channelId": msg["channels"][0]["id"]}]}))
            break
    while subscribing and view.stats.subscriptions == 0:
        await asyncio.sleep(0.01)
    for seq in range(1, 20001):  # 40 MB while the client reads one frame every 10 ms (or none)
        record(seq)
        if seq % 50 == 0 and subscribing and not closed:
            try:
                await asyncio.wait_for(ws.recv(), 0.01)
                read += 1
            except TimeoutError:
                pass
            except websockets.ConnectionClosed:  # the SDK disconnected it
                closed = True
    await ws.close()
    return read, closed

record(0)
read, closed = asyncio.run(slow_client())
print(json.dumps({"read": read, "closed": closed, **view.close().as_dict()}))
"""


def _slow_client_run(mode: str) -> dict[str, Any]:
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-c", SLOW_CLIENT_RUN, mode], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def test_a_slow_client_is_noticed() -> None:
    """A client with a 4 KiB receive buffer that reads one frame every 10 ms while 20,000
    records of 2 kB go through a view with a backlog of 16 (a fresh process: the SDK says a
    client's outbox is full at most once per 30 s per process): the SDK drops that client's
    oldest messages (its notice counted) or, when the server's time messages fill the client's
    control queue first, disconnects it (counted); which comes first is the threads' race.
    Every record was handed on without waiting."""
    got = _slow_client_run("subscribed")
    assert got["published"] == 20001 and got["read"] < 20001
    assert got["slow_clients"] == 1 and got["slow_client_notices"] + got["slow_clients_disconnected"] >= 1, got


def test_a_stuck_client_is_disconnected_and_counted() -> None:
    """A client that subscribes to nothing and reads nothing while 20,000 records go through
    (each with a time message, a control message for every client): once its control queue (16)
    is full the SDK disconnects it, which the view counts; no data was queued for it."""
    got = _slow_client_run("idle")
    assert got["published"] == 20001
    assert (got["slow_clients_disconnected"], got["slow_clients"], got["slow_client_notices"]) == (1, 1, 0), got


def test_the_sdk_log_lines_are_counted_per_client() -> None:
    """What foxglove-sdk 0.30 logs (its lines, as its Rust source writes them): outbox-full
    notices, and a client unregistered without having closed the connection itself."""
    from workbench.live.view import SDK_LOGGER, LiveStats, SdkLogCounter

    stats = LiveStats()
    counter = SdkLogCounter(stats)
    lines = [
        "Registered client 127.0.0.1:5000",
        "outbox for client 127.0.0.1:5000 full",
        "outbox for client 127.0.0.1:5000 full",
        "Unregistered client 127.0.0.1:5000",  # the SDK let it go: its control queue was full
        "Registered client 127.0.0.1:6000",
        "Connection closed by client 127.0.0.1:6000",
        "Unregistered client 127.0.0.1:6000",  # it left on its own
        "Registered client 127.0.0.1:7000",
        "Started server on 127.0.0.1:8765",
    ]
    for text in lines:
        counter.handle(logging.LogRecord(SDK_LOGGER, logging.INFO, __file__, 0, text, None, None))
    assert (stats.slow_client_notices, stats.slow_clients_disconnected, stats.slow_clients) == (2, 1, 1)
    counter.stopping = True  # the view's own stop unregisters everyone
    counter.handle(logging.LogRecord(SDK_LOGGER, logging.INFO, __file__, 0, "Unregistered client 127.0.0.1:7000", None, None))
    assert stats.slow_clients_disconnected == 1


def feed_every_topic(view: LiveView, topics: list[tuple[str, dict[str, Any]]], stop: threading.Event) -> None:
    """One record on each topic every 10 ms of wall time, straight into the view, until ``stop``."""
    n = 0
    while not stop.is_set():
        n += 1
        for topic, schema in topics:
            view.on_record(topic, str(schema["title"]), schema, json.dumps({"sim_time_s": n / 64}).encode(), 4096.0 + n)
        stop.wait(0.01)


def test_a_client_subscribing_on_advertisement_gets_every_rig_channel() -> None:
    """Every channel of the rig exists before the server serves: a client that subscribes to each
    channel the moment its advertisement arrives (as the Foxglove app does) is refused none and
    gets data from each, while records flow on all of them."""
    from workbench.recording.schemas import rig_topics

    topics = rig_topics("lv")
    view = LiveView("127.0.0.1", 0, rate_hz=1e6, topics=topics)
    stop = threading.Event()
    feeder = threading.Thread(target=feed_every_topic, args=(view, topics, stop), daemon=True)
    feeder.start()  # before the client comes: data flows on every channel while it subscribes
    try:
        got = asyncio.run(watch(view.url, None, 60.0, until_topic_count=len(topics)))
    finally:
        stop.set()
        feeder.join(10)
        stats = view.close()
    assert [s for s in got.statuses if "Unknown channel" in s["message"]] == []
    assert {c["topic"] for c in got.channels.values()} == {t for t, _ in topics}
    assert {m[0] for m in got.messages} == {t for t, _ in topics}
    assert stats.late_channels == 0 and stats.subscriptions == len(topics)


def test_a_topic_outside_the_rigs_list_is_created_late_and_counted() -> None:
    view = LiveView("127.0.0.1", 0, topics=[("/can", {"title": "ralf.CanFrame"})])
    try:
        view.on_record("/ralf/other/plant/truth", "ralf.GroundTruth", {"title": "ralf.GroundTruth"}, b'{"sim_time_s": 1.0}', 1.0)
        view.on_record("/can", "ralf.CanFrame", {"title": "ralf.CanFrame"}, b'{"sim_time_s": 1.0}', 1.0)
    finally:
        stats = view.close()
    assert (stats.late_channels, stats.published) == (1, 2)
