"""Acceptance filters on the wire arbiter (service_kit/can_wire/acceptance.py,
hub.py, hub_bus.py): python-can's rule exactly (against python-can's own
software filter), applied per client on a manual clock, over the socket from
python-can's filter API, and by a stock tool in another process
(.ci/loopback-netns)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from service_kit.can_wire import hub_protocol as proto
from service_kit.can_wire.acceptance import NEVER, NO_FRAME, FilterError, accepts, compile_filters
from service_kit.can_wire.hub import Hub, HubServer
from service_kit.can_wire.wire_bus import ManualWireClock

BITRATE = 1_000_000


class Endpoint:
    """A connected bus as the arbiter sees it, keeping what it is given."""

    def __init__(self, filters: list[dict[str, Any]] | None = None, receive_own: bool = True) -> None:
        self._open = True
        self.in_wire = 0
        self.receive_own = receive_own
        self.filters = compile_filters(filters)
        self.got: list[proto.Delivered] = []

    def put(self, packet: bytes) -> None:
        d = proto.decode_delivery(packet)
        assert d is not None
        self.got.append(d)


def run_clock(clock: ManualWireClock, limit: int = 100_000) -> None:
    for _ in range(limit):
        t = clock.next_event_ns()
        if t is None:
            return
        clock.advance_to(t)
    raise AssertionError("the wire did not settle")


def message(ident: int, extended: bool = False, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=ident, is_extended_id=extended, data=data)


# -- the rule: python-can's own software filter is the reference ------------------------------------------

filter_strategy = st.fixed_dictionaries(
    {"can_id": st.integers(0, 2**32 - 1), "can_mask": st.one_of(st.integers(0, 0x7FF), st.integers(0, 2**32 - 1))},
    optional={"extended": st.booleans()},
)
frame_strategy = st.one_of(
    st.tuples(st.integers(0, 0x7FF), st.just(False)),
    st.tuples(st.integers(0, 0x1FFFFFFF), st.just(True)),
)


@pytest.fixture(scope="module")
def reference_bus() -> Iterator[can.BusABC]:
    bus = can.Bus(interface="virtual", channel="acceptance-reference")
    yield bus
    bus.shutdown()


@settings(max_examples=300, deadline=None)
@given(st.lists(filter_strategy, max_size=5), st.lists(frame_strategy, min_size=1, max_size=20))
def test_acceptance_is_python_cans_rule(reference_bus: can.BusABC, filters: list[dict[str, Any]], frames: list[tuple[int, bool]]) -> None:
    reference_bus.set_filters(filters)  # type: ignore[arg-type]
    compiled = compile_filters(filters)
    packet_filters = proto.decode_filters(proto.encode_filters(compiled))  # the same rule after the trip to the arbiter
    assert packet_filters is not None
    for ident, extended in frames:
        expected = reference_bus._matches_filters(message(ident, extended))
        assert accepts(compiled, ident, extended) is expected
        assert accepts(packet_filters[0], ident, extended) is expected


def test_filters_that_are_no_filters_are_refused_and_no_frame_passes_no_frame() -> None:
    for bad in ([{"can_id": 1}], [{"can_id": "0x80", "can_mask": 0x7FF}], [{"can_id": -1, "can_mask": 0x7FF}], [7]):
        with pytest.raises(FilterError):
            compile_filters(bad)  # type: ignore[arg-type]
    assert compile_filters(None) is None and compile_filters([]) is None
    assert compile_filters(NO_FRAME) == (NEVER,)
    assert not any(accepts(compile_filters(NO_FRAME), i, e) for i, e in ((0, False), (0x7FF, False), (0, True), (0x1FFFFFFF, True)))


def test_filter_packets_refuse_junk() -> None:
    ok = proto.encode_filters(((0x80, 0x7FF, 1), (0x1234, 0x1FFFFFFF, 2)))
    assert proto.decode_filters(ok) == (((0x80, 0x7FF, 1), (0x1234, 0x1FFFFFFF, 2)),)
    assert proto.decode_filters(proto.encode_filters(None)) == (None,)
    assert proto.decode_filters(ok[:-1]) is None  # cut short
    assert proto.decode_filters(ok + b"\0") is None  # too long
    assert proto.decode_filters(b"RWx1" + ok[4:]) is None  # wrong magic
    assert proto.decode_filters(proto.encode_filters(((0x80, 0x7FF, 3),))) is None  # no such kind
    assert proto.decode_filters(proto.encode_filters(((0x20000000, 0x7FF, 0),))) is None  # no such identifier
    assert proto.decode_send(ok) is None and proto.decode_options(ok) is None
    with pytest.raises(ValueError, match="at most"):
        proto.encode_filters(((0x80, 0x7FF, 0),) * (proto.MAX_FILTERS + 1))


# -- the arbiter, on a manual clock ------------------------------------------------------------------------


def test_a_filtered_client_gets_exactly_the_accepted_frames_at_the_same_moments() -> None:
    clock = ManualWireClock()
    hub = Hub(BITRATE, clock=clock)
    try:
        sync_tpdo = [{"can_id": 0x080, "can_mask": 0x7FF, "extended": False}, {"can_id": 0x181, "can_mask": 0x7FF}]
        sender = Endpoint(filters=[{"can_id": 0x181, "can_mask": 0x7FF}])  # its own frames pass its filters too
        filtered, everything, deaf = Endpoint(filters=sync_tpdo), Endpoint(), Endpoint(filters=NO_FRAME)
        for ep in (sender, filtered, everything, deaf):
            hub.attach(ep)
        sent = [message(0x080), message(0x181, data=b"\1" * 8), message(0x300), message(0x181, extended=True), message(0x7FF), message(0x080)]
        for t, m in enumerate(sent):
            clock.advance_to(t * 10_000)
            assert hub.submit(sender, m)
        run_clock(clock)
        assert [(d.msg.arbitration_id, d.msg.is_extended_id) for d in everything.got] == [(m.arbitration_id, m.is_extended_id) for m in sent]
        accepted = [d for d in everything.got if (d.msg.arbitration_id, d.msg.is_extended_id) in ((0x080, False), (0x181, False), (0x181, True))]
        assert [(d.msg.arbitration_id, d.msg.is_extended_id, d.last_bit_ns) for d in filtered.got] == [
            (d.msg.arbitration_id, d.msg.is_extended_id, d.last_bit_ns) for d in accepted
        ]
        assert [(d.msg.arbitration_id, d.own) for d in sender.got] == [(0x181, True), (0x181, True)]
        assert deaf.got == []
        report = hub.report()
        assert report["filtered_per_client"] == {"client-1": 4, "client-2": 2, "client-4": 6}
        assert report["clients"]["filtered"] == 12 and report["frames"] == len(sent)
    finally:
        hub.close()


def test_filters_change_nothing_on_the_wire() -> None:
    """Filters are the receivers' business: the wire's timing and figures are the same with and without."""

    def run(filters: list[dict[str, Any]] | None) -> tuple[list[int], dict[str, Any]]:
        clock = ManualWireClock()
        hub = Hub(BITRATE, clock=clock)
        try:
            a, b, c = Endpoint(filters=filters), Endpoint(filters=filters), Endpoint()
            for ep in (a, b, c):
                hub.attach(ep)
            for i in range(40):
                clock.advance_to(i * 7_000)
                hub.submit(a if i % 2 else b, message(0x100 + (i * 37) % 0x600, data=bytes([i]) * (i % 9)))
            run_clock(clock)
            report = hub.report()
            return [d.last_bit_ns for d in c.got], {k: v for k, v in report.items() if k not in ("clients", "filtered_per_client")}
        finally:
            hub.close()

    assert run(None) == run([{"can_id": 0x080, "can_mask": 0x7FF}])


# -- over the socket, from python-can's filter API ---------------------------------------------------------


@pytest.fixture
def private_dir() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="hf") as d:
        os.chmod(d, 0o700)
        yield Path(d)


def _wait(pred: Callable[[], bool], timeout: float = 30.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def test_python_can_filters_reach_the_arbiter_and_a_flood_does_not_overrun_a_filtered_client(private_dir: Path) -> None:
    server = HubServer(private_dir / "s", BITRATE, max_outbox=16, max_pending=10_000).start()
    buses: list[can.BusABC] = []
    try:
        path = str(private_dir / "s")
        sync_only = can.Bus(interface="ralfhub", channel=path, can_filters=[{"can_id": 0x080, "can_mask": 0x7FF, "extended": False}])
        unread = can.Bus(interface="ralfhub", channel=path)  # no filters, never read: its outbox overruns
        sender = can.Bus(interface="ralfhub", channel=path)
        buses += [sync_only, unread, sender]
        assert sync_only.hub_filters == ((0x080, 0x7FF, 1),)  # type: ignore[attr-defined]
        assert _wait(lambda: server.hub.n_clients == 3)
        n = 500
        for i in range(n):
            sender.send(message(0x300 + i % 16, data=bytes(8)))
        sender.send(message(0x080))
        assert _wait(lambda: server.report()["frames"] == n + 1)
        got = sync_only.recv(10.0)
        assert got is not None and got.arbitration_id == 0x080
        assert sync_only.recv(0.2) is None
        report = server.report()
        assert report["filtered_per_client"] == {"client-1": n}
        assert report["clients"]["overruns"] > 0  # the unread client without filters lost frames; the filtered one none (it got its SYNC)

        # changed at run time; the software check covers frames already on their way
        sync_only.set_filters([{"can_id": 0x300, "can_mask": 0x7F0}])
        sender.send(message(0x080))
        sender.send(message(0x30A))
        got = sync_only.recv(10.0)
        assert got is not None and got.arbitration_id == 0x30A
        assert _wait(lambda: server.report()["filtered_per_client"]["client-1"] == n + 1)

        # more filters than the arbiter holds: it sends every frame, the bus filters alone
        many = [{"can_id": 0x400 + i, "can_mask": 0x7FF} for i in range(proto.MAX_FILTERS + 1)]
        sync_only.set_filters(many)
        assert sync_only.hub_filters is None  # type: ignore[attr-defined]
        sender.send(message(0x080))
        sender.send(message(0x400 + proto.MAX_FILTERS))
        got = sync_only.recv(10.0)
        assert got is not None and got.arbitration_id == 0x400 + proto.MAX_FILTERS

        with pytest.raises(can.CanOperationError, match="can_mask"):
            sync_only.set_filters([{"can_id": 0x80}])  # type: ignore[typeddict-item]
        with pytest.raises(can.CanOperationError, match="can_mask"):
            can.Bus(interface="ralfhub", channel=path, can_filters=[{"can_id": 0x80}])
    finally:
        for bus in buses:
            bus.shutdown()
        server.close()


# -- across processes (.ci/loopback-netns) -----------------------------------------------------------------


def test_a_stock_logger_with_filters_gets_only_its_frames_and_the_arbiter_counts_the_rest(private_dir: Path) -> None:
    path, stats = private_dir / "s", private_dir / "stats.json"
    logs = {"filtered": private_dir / "filtered.asc", "all": private_dir / "all.asc"}
    hub = subprocess.Popen(
        [sys.executable, "-m", "service_kit.can_wire.hub", "--socket", str(path), "--bitrate", str(BITRATE), "--stats", str(stats)],
        stdout=subprocess.PIPE,
    )
    assert hub.stdout is not None
    assert "can wire hub:" in hub.stdout.readline().decode()
    loggers: list[subprocess.Popen[bytes]] = []
    try:
        for name, extra in (("filtered", ["--filter", "080:7FF", "181:7FF"]), ("all", [])):
            loggers.append(
                subprocess.Popen(
                    [sys.executable, "-m", "can.logger", "-i", "ralfhub", "-c", str(path), "-f", str(logs[name]), *extra],
                    stdout=subprocess.DEVNULL,
                    preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),  # a background job of a script ignores SIGINT
                )
            )
        assert _wait(lambda: all(p.exists() for p in logs.values()), 120.0)  # can.logger makes its file once its bus is connected
        sender = can.Bus(interface="ralfhub", channel=str(path))
        probe = can.Bus(interface="ralfhub", channel=str(path))
        sent = [message(ident, data=bytes([i]) * 4) for i, ident in enumerate([0x080, 0x181, 0x300, 0x301, 0x080, 0x181, 0x7E0, 0x0A0] * 5)]
        for m in sent:
            sender.send(m)
        assert all(probe.recv(10.0) is not None for _ in sent)
        sender.shutdown()
        probe.shutdown()
        time.sleep(0.5)
    finally:
        for p in loggers:
            p.send_signal(signal.SIGINT)
            p.wait(timeout=20)
        hub.terminate()
        hub.wait(timeout=20)
    seen = {name: [m.arbitration_id for m in can.LogReader(log) if not m.is_error_frame] for name, log in logs.items()}
    assert seen["all"] == [m.arbitration_id for m in sent]
    assert seen["filtered"] == [m.arbitration_id for m in sent if m.arbitration_id in (0x080, 0x181)]
    report = json.loads(stats.read_text())
    assert report["clients"]["filtered"] == len(sent) - len(seen["filtered"])
    assert list(report["filtered_per_client"].values()) == [len(sent) - len(seen["filtered"])]


def test_the_rig_opens_its_bus_filtered_on_the_arbiter_only(private_dir: Path) -> None:
    from protocol.settings import CommonSettings
    from service_kit.transport import open_can_bus

    consumes: list[can.typechecking.CanFilter] = [{"can_id": 0x080, "can_mask": 0x7FF}]
    server = HubServer(private_dir / "s", BITRATE).start()
    try:
        hub_bus = open_can_bus(CommonSettings(can_interface="ralfhub", can_channel=str(private_dir / "s")), consumes=consumes)
        plain = open_can_bus(CommonSettings(can_interface="virtual", can_channel="filters-plain"), consumes=consumes)
        try:
            assert hub_bus.hub_filters == ((0x080, 0x7FF, 0),)  # type: ignore[attr-defined]
            assert plain.filters is None
        finally:
            hub_bus.shutdown()
            plain.shutdown()
    finally:
        server.close()
