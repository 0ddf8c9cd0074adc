"""The wire arbiter (service_kit/can_wire/hub.py): deterministic on a manual
clock against the bus model, bounded against bad clients, and joined by stock
tools from other processes (those tests run in .ci/loopback-netns)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import canopen
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire import hub_protocol as proto
from service_kit.can_wire.arbitration import INTERMISSION_BITS, QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits, frame_of_message
from service_kit.can_wire.bus_load import bus_load, intervals_from_run
from service_kit.can_wire.hub import Hub, HubError, HubServer, check_socket_path
from service_kit.can_wire.wire_bus import ManualWireClock

BITRATE = 1_000_000
BIT_NS = 1000


class Endpoint:
    """A connected bus as the arbiter sees it, keeping what it is given."""

    def __init__(self, name: str, on_delivery: Callable[[proto.Delivered], None] | None = None) -> None:
        self.name = name
        self._open = True
        self.in_wire = 0
        self.receive_own = True
        self.filters: tuple[tuple[int, int, int], ...] | None = None
        self.got: list[proto.Delivered] = []
        self.on_delivery = on_delivery

    def put(self, packet: bytes) -> None:
        d = proto.decode_delivery(packet)
        assert d is not None
        self.got.append(d)
        if self.on_delivery is not None:
            self.on_delivery(d)


def run_clock(clock: ManualWireClock, limit: int = 10_000) -> None:
    for _ in range(limit):
        t = clock.next_event_ns()
        if t is None:
            return
        clock.advance_to(t)
    raise AssertionError("the wire did not settle")


def msg(ident: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=ident, data=data, is_extended_id=False)


frames_strategy = st.lists(
    st.tuples(st.sampled_from(["a", "b", "c"]), st.integers(0, 2_000_000), st.integers(0, 0x7EF), st.binary(max_size=8)),
    min_size=1,
    max_size=25,
)


@settings(max_examples=30, deadline=None)
@given(frames_strategy)
def test_deliveries_are_the_bus_models(spec: list[tuple[str, int, int, bytes]]) -> None:
    """Frames of three clients queued at given times end exactly when simulate() ends them, in its order."""
    spec = sorted(spec, key=lambda s: s[1])
    clock = ManualWireClock()
    hub = Hub(BITRATE, clock=clock, tx_order="priority", window_ns=200_000)
    eps = {n: Endpoint(n) for n in "abc"}
    listener = Endpoint("listener")
    for ep in [*eps.values(), listener]:
        hub.attach(ep)
    for node, t, ident, data in spec:
        if clock.now_ns() < t:
            clock.advance_to(t)  # delivers what ended before t
        assert hub.submit(eps[node], msg(ident, data))
    run_clock(clock)
    run = simulate([QueuedFrame(n, t, frame_bits(i, d)) for n, t, i, d in spec], BITRATE, nodes=["listener"])
    want = [(tx.arbitration_id, tx.last_bit_ns) for tx in run.transmissions]
    assert [(d.msg.arbitration_id, d.last_bit_ns) for d in listener.got] == want
    assert [d.msg.timestamp for d in listener.got] == [t / 1e9 for _, t in want]
    assert all(not d.own for d in listener.got)
    own = [d for d in eps["a"].got if d.own]
    assert len(own) == sum(1 for s in spec if s[0] == "a")
    report = hub.report()
    ivs = intervals_from_run(run)
    reference = bus_load(ivs, BITRATE, hub.stats.window_ns, start_ns=ivs[0].start_ns)
    full = reference.windows[:-1] or reference.windows
    assert report["peak_window_busy_pct"] == pytest.approx(100 * max(w.busy for w in full), abs=1e-9)
    assert report["frames"] == len(spec)
    assert report["bits"] == sum(frame_bits(i, d).n_bits for _, _, i, d in spec)
    hub.close()


TPDO1 = bytes([0x12, 0x80, 0xFF, 0x7F, 0x00, 0x08, 0x55, 0xAA])


def plant_answering_sync(hub: Hub) -> Endpoint:
    """A plant that sends TPDO1 the moment it has received a SYNC whole."""

    def answer(d: proto.Delivered) -> None:
        if d.msg.arbitration_id == 0x080 and not d.own:
            assert hub.submit(plant, msg(0x181, TPDO1))

    plant = Endpoint("plant", answer)
    return plant


@pytest.mark.parametrize("competitor", [None, 0x020, 0x300])
def test_sync_to_tpdo1_is_never_below_its_floor(competitor: int | None) -> None:
    """SYNC's last bit to TPDO1's last bit at 1 Mbit/s: the intermission plus TPDO1's bits
    to EOF when the wire is free, plus a higher-priority frame queued with the answer;
    a lower-priority one waits."""
    clock = ManualWireClock()
    hub = Hub(BITRATE, clock=clock)
    master, other = Endpoint("controller"), Endpoint("restbus")
    plant = plant_answering_sync(hub)

    def restbus(d: proto.Delivered) -> None:
        if competitor is not None and d.msg.arbitration_id == 0x080:
            assert hub.submit(other, msg(competitor, bytes(8)))

    other.on_delivery = restbus
    for ep in (master, plant, other):
        hub.attach(ep)
    for k in range(5):
        clock.advance_to(k * 1_000_000)
        hub.submit(master, msg(0x080))
        run_clock(clock)
    tpdo = frame_bits(0x181, TPDO1)
    floor_ns = (INTERMISSION_BITS + tpdo.n_bits_to_eof) * BIT_NS
    extra = frame_bits(competitor, bytes(8)).n_bits * BIT_NS if competitor is not None and competitor < 0x181 else 0
    syncs = [d.last_bit_ns for d in master.got if d.msg.arbitration_id == 0x080]
    tpdos = [d.last_bit_ns for d in master.got if d.msg.arbitration_id == 0x181]
    assert len(syncs) == len(tpdos) == 5
    assert [t - s for s, t in zip(syncs, tpdos, strict=True)] == [floor_ns + extra] * 5
    report = hub.report()
    assert report["sync_to_tpdo1_us"]["min"] == (floor_ns + extra) / 1e3
    assert report["sync_to_tpdo1_floor_margin_min_us"] == extra / 1e3
    delays = report["queuing_delay_us"]["0x181"]
    assert delays["max"] == (INTERMISSION_BITS * BIT_NS + extra) / 1e3  # queued at SYNC's last bit, waits for the bus
    hub.close()


def test_a_node_transmit_fifo_keeps_its_order() -> None:
    """By default a client's frames leave in the order it sent them (RPDO1 before the next
    SYNC), other nodes' frames still arbitrate against its oldest; "priority" reorders them."""
    cases = (("fifo", None, [0x300, 0x100, 0x201, 0x080]), ("priority", None, [0x300, 0x080, 0x100, 0x201]), ("fifo", False, [0x300, 0x080, 0x100, 0x201]))
    for order, own_choice, want in cases:
        clock = ManualWireClock()
        hub = Hub(BITRATE, clock=clock, tx_order=order)
        controller, other, listener = Endpoint("controller"), Endpoint("other"), Endpoint("listener")
        if own_choice is not None:
            controller.fifo = own_choice  # type: ignore[attr-defined]  # a client's own choice (OPTIONS)
        for ep in (controller, other, listener):
            hub.attach(ep)
        hub.submit(other, msg(0x300))  # on the wire first: the rest queue behind it
        clock.advance_to(1)
        hub.submit(controller, msg(0x201, bytes(4)))
        hub.submit(controller, msg(0x080))
        hub.submit(other, msg(0x100))
        run_clock(clock)
        assert [d.msg.arbitration_id for d in listener.got] == want, order
        hub.close()


def test_a_full_transmit_buffer_refuses_and_counts() -> None:
    clock = ManualWireClock()
    hub = Hub(BITRATE, clock=clock, max_pending=3)
    a = Endpoint("a")
    hub.attach(a)
    assert [hub.submit(a, msg(0x100 + i)) for i in range(5)] == [True, True, True, False, False]
    assert hub.submit(a, can.Message(arbitration_id=0x800, is_extended_id=False, check=False)) is False
    assert hub.counters.refused_frames == 3
    run_clock(clock)
    assert hub.report()["frames"] == 3
    hub.close()


def test_frames_of_a_detached_client_are_dropped_and_counted() -> None:
    clock = ManualWireClock()
    hub = Hub(BITRATE, clock=clock)
    a, b = Endpoint("a"), Endpoint("b")
    hub.attach(a)
    hub.attach(b)
    hub.submit(a, msg(0x100, bytes(8)))
    hub.submit(a, msg(0x200))
    hub.submit(b, msg(0x300))
    clock.advance_to(1)  # 0x100 goes on the wire
    hub.detach(a)
    run_clock(clock)
    assert [d.msg.arbitration_id for d in b.got] == [0x100, 0x300]  # the frame on the wire was sent
    assert hub.wire.dropped == 1
    hub.close()


def test_protocol_refuses_junk() -> None:
    good = proto.encode_send(msg(0x181, b"\x01\x02"))
    back = proto.decode_send(good)
    assert back is not None and back.arbitration_id == 0x181 and bytes(back.data) == b"\x01\x02"
    remote = proto.decode_send(proto.encode_send(can.Message(arbitration_id=0x1ABCDEF0, is_remote_frame=True, dlc=3)))
    assert remote is not None and remote.is_remote_frame and remote.is_extended_id and remote.dlc == 3
    for junk in (b"", b"hello", good + b"x", b"XXXX" + good[4:], good[:9] + b"\x09" + good[10:], good[:8] + b"\x04" + good[9:]):
        assert proto.decode_send(junk) is None
    assert proto.decode_options(proto.encode_options(True, "priority")) == (True, "priority")
    assert proto.decode_options(proto.encode_options(False)) == (False, None)
    assert proto.decode_options(proto.OPTIONS.pack(proto.OPTIONS_MAGIC, 7)) is None
    too_big = proto.SEND.pack(proto.SEND_MAGIC, 0x800, 0, 0, bytes(8))
    assert proto.decode_send(too_big) is None


@pytest.fixture
def private_dir() -> Iterator[Path]:
    path = Path(tempfile.mkdtemp(prefix="hub-", dir="/tmp"))  # short: a Unix socket path has 107 bytes
    os.chmod(path, 0o700)
    yield path
    for p in path.iterdir():
        p.unlink()
    path.rmdir()


def test_socket_path_checks(private_dir: Path) -> None:
    with pytest.raises(HubError, match="longer than"):
        check_socket_path(private_dir / ("x" * 120))
    open_dir = private_dir / "open"
    open_dir.mkdir()
    os.chmod(open_dir, 0o777)
    with pytest.raises(HubError, match="private"):
        check_socket_path(open_dir / "s")
    open_dir.rmdir()
    server = HubServer(private_dir / "s", BITRATE)
    try:
        assert (os.stat(private_dir / "s").st_mode & 0o777) == 0o600
        with pytest.raises(HubError, match="exists"):
            HubServer(private_dir / "s", BITRATE)
    finally:
        server.close()


def _wait(pred: Callable[[], bool], timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def test_junk_overruns_and_vanished_clients_are_counted(private_dir: Path) -> None:
    path = private_dir / "s"
    server = HubServer(path, BITRATE, max_outbox=4, max_pending=100_000).start()
    try:
        raw = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        raw.connect(str(path))
        assert proto.decode_hello(raw.recv(64)) == BITRATE
        for junk in (b"junk", b"\0" * 18, b"x" * 200):
            raw.send(junk)
        assert _wait(lambda: server.hub.counters.junk == 3)
        sender = can.Bus(interface="ralfhub", channel=str(path), bitrate=BITRATE)
        for i in range(5000):  # raw never reads: the kernel's buffer fills, then its outbox
            sender.send(msg(0x100 + i % 0x100))
            if i % 100 == 99 and _wait(lambda: server.hub.counters.overruns > 0, 0.2):
                break
        assert server.hub.counters.overruns > 0
        assert server.hub.n_clients == 2  # a reader that lags loses its oldest frames, not its bus
        raw.setblocking(False)
        got = 0
        try:
            while proto.decode_delivery(raw.recv(64)) is not None:
                got += 1
        except BlockingIOError:
            pass
        assert got > 0
        raw.close()
        gone = can.Bus(interface="ralfhub", channel=str(path))
        gone.shutdown()
        assert _wait(lambda: server.hub.counters.vanished == 2)  # raw and gone
        assert server.hub.n_clients == 1
        prio = can.Bus(interface="ralfhub", channel=str(path), tx_order="priority")
        assert _wait(lambda: [c.fifo for c in server._clients] == [True, False])  # the sender: the default; prio: its choice
        prio.shutdown()
        assert _wait(lambda: server.hub.counters.vanished == 3)
        with pytest.raises(can.CanInitializationError, match="not 500000"):
            can.Bus(interface="ralfhub", channel=str(path), bitrate=500_000)
        sender.shutdown()
    finally:
        report = server.close()
    assert report["clients"]["junk"] == 3 and report["clients"]["overruns"] > 0 and report["clients"]["connected"] == 5


# -- across processes (.ci/loopback-netns) ------------------------------------------------------------------------


def _start_hub(path: Path, stats: Path) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "service_kit.can_wire.hub", "--socket", str(path), "--bitrate", str(BITRATE), "--stats", str(stats)],
        stdout=subprocess.PIPE,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()
    assert "can wire hub:" in line, line
    return proc


def _stop(proc: subprocess.Popen[bytes]) -> None:
    proc.terminate()
    proc.wait(timeout=20)


def test_stock_logger_in_another_process_sees_the_wire(private_dir: Path) -> None:
    path, stats, log = private_dir / "s", private_dir / "stats.json", private_dir / "bus.asc"
    hub = _start_hub(path, stats)
    logger = None
    try:
        logger = subprocess.Popen(
            [sys.executable, "-m", "can.logger", "-i", "ralfhub", "-c", str(path), "-f", str(log)],
            stdout=subprocess.DEVNULL,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background job of a script ignores SIGINT
        )
        sender = can.Bus(interface="ralfhub", channel=str(path), bitrate=BITRATE, receive_own_messages=True)
        probe = can.Bus(interface="ralfhub", channel=str(path))
        assert _wait(log.exists, 120.0)  # can.logger makes its file once its bus is connected
        sent = [msg(0x300 - i, bytes([i] * 8)) for i in range(20)]
        for m in sent:
            sender.send(m)
        got = [probe.recv(5.0) for _ in sent]
        assert all(g is not None for g in got)
        sender.shutdown()
        probe.shutdown()
        time.sleep(0.5)
    finally:
        try:
            if logger is not None:
                logger.send_signal(signal.SIGINT)
                logger.wait(timeout=20)
        finally:
            _stop(hub)
    frames = [m for m in can.LogReader(log) if not m.is_error_frame]
    assert len(frames) == 20
    stamps = [m.timestamp for m in frames]
    bits = [frame_of_message(m).n_bits_to_eof for m in frames]
    # one wire: each frame ends at least its own bits (and the intermission) after the previous one
    for prev, cur, n in zip(stamps, stamps[1:], bits[1:], strict=False):
        assert cur - prev >= (n + INTERMISSION_BITS) * BIT_NS / 1e9 - 2e-6  # ASC keeps µs
    import json

    report = json.loads(stats.read_text())
    assert report["frames"] == 20 and report["clients"]["connected"] >= 3


def test_canopen_master_reads_the_plant_node_through_the_arbiter(private_dir: Path) -> None:
    """A stock canopen master in this process, the plant's node in another, the arbiter in a third."""
    sys.path.append(os.getcwd())
    path, stats = private_dir / "s", private_dir / "stats.json"
    hub = _start_hub(path, stats)
    node_code = (
        "import os, sys, threading, signal; sys.path.append(os.getcwd()); import can\n"
        "from plant_emulator.canopen_node import CanopenNode, NodeConfig, run_node\n"
        "from tests.plant.support import FakeApp\n"
        f"bus = can.Bus(interface='ralfhub', channel={str(path)!r}, bitrate={BITRATE})\n"
        "stop = threading.Event(); signal.signal(signal.SIGTERM, lambda *a: stop.set())\n"
        "print('ready', flush=True)\n"
        "run_node(bus, CanopenNode(FakeApp(volts=(3.2, -1.1, 0.25, -9.5)), NodeConfig(watchdog_periods=0)), stop)\n"
        "bus.shutdown()\n"
    )
    node = subprocess.Popen([sys.executable, "-c", node_code], stdout=subprocess.PIPE, cwd=os.getcwd())
    network = canopen.Network()
    try:
        assert node.stdout is not None and node.stdout.readline().strip() == b"ready"
        network.connect(interface="ralfhub", channel=str(path), bitrate=BITRATE)
        from tests.plant.support import EDS

        remote = network.add_node(1, str(EDS))
        assert remote.sdo.upload(0x1000, 0) == (0x000C0191).to_bytes(4, "little")
        assert remote.sdo[0x1000].raw == 0x000C0191
        remote.nmt.state = "OPERATIONAL"
        remote.tpdo.read()
        got = threading.Event()
        remote.tpdo[1].add_callback(lambda _m: got.set())
        assert _wait(lambda: remote.nmt.state == "OPERATIONAL")
        network.sync.transmit()
        assert got.wait(5.0)
    finally:
        try:
            network.disconnect()
            node.terminate()
            node.wait(timeout=20)
        finally:
            _stop(hub)
    import json

    report = json.loads(stats.read_text())
    assert report["sync_to_tpdo1_floor_margin_min_us"] >= 0
    assert report["clients"]["vanished"] == 2 and report["clients"]["junk"] == 0


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--socket", "/nonexistent-folder/s", "--bitrate", "1000000"], "/nonexistent-folder"),
        (["--socket", "SOCKET", "--bitrate", "300000"], "300000"),
    ],
)
def test_hub_cli_refuses_with_one_line(argv: list[str], expected: str, private_dir: Path) -> None:
    argv = [str(private_dir / "s") if a == "SOCKET" else a for a in argv]
    proc = subprocess.run([sys.executable, "-m", "service_kit.can_wire.hub", *argv], capture_output=True, text=True, check=False, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and expected in proc.stderr and "Traceback" not in proc.stderr
    assert not (private_dir / "s").exists()
