"""Round-trip measurements. A *pinger* does one round trip per ``once()``
and returns its duration in seconds; :func:`interleave` runs several
pingers in alternating blocks, so a measurement and its floor see the same
machine state (the machine is shared: other processes come and go)."""

from __future__ import annotations

import json
import math
import queue
import socket
import struct
import time
from collections.abc import Callable
from typing import Any, Protocol

import can
import numpy as np
import zenoh

from protocol import can_map
from protocol.batch_codec import SampleBatch, encode_batch
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import BlockFlag, Health, Interrupt, decode
from service_kit.access import tls_section
from service_kit.can_udp import LoopFreeUdpMulticastBus
from service_kit.zenoh_log import init_zenoh_log
from workbench.bench.procs import BenchError

_SEQ = struct.Struct("<Q")
_perf = time.perf_counter


class Pinger(Protocol):
    name: str

    def once(self) -> float: ...


def interleave(pingers: list[Pinger], iterations: int, warmup: int, block: int = 50, progress: Callable[[], None] | None = None) -> dict[str, list[float]]:
    """``iterations`` timed round trips of every pinger (after ``warmup``
    untimed ones each), alternating in blocks of ``block``."""
    for p in pingers:
        for _ in range(warmup):
            p.once()
    out: dict[str, list[float]] = {p.name: [] for p in pingers}
    done = 0
    while done < iterations:
        step = min(block, iterations - done)
        for p in pingers:
            samples = out[p.name]
            for _ in range(step):
                samples.append(p.once())
        done += step
        if progress is not None:
            progress()
    return out


def zenoh_session(listen: list[str] | None = None, connect: list[str] | None = None, tls: tuple[str, str, str] | None = None) -> zenoh.Session:
    """A peer session on explicit endpoints, multicast scouting off (``tls``:
    mutual TLS with these authority, certificate and key files)."""
    init_zenoh_log()
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    if tls is not None:
        config.insert_json5("transport/link/tls", json.dumps(tls_section(*tls)))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(connect))
    return zenoh.open(config)


def _publisher(session: zenoh.Session, key: str) -> zenoh.Publisher:
    return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.REAL_TIME, express=True)


# --- bare floors ---------------------------------------------------------------------------


class UdpPinger:
    """Bare UDP round trip on loopback to :func:`workbench.bench.peer.udp_echo`."""

    name = "udp_pingpong"

    def __init__(self, port: int, size: int, timeout_s: float = 2.0) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.connect(("127.0.0.1", port))
        self.sock.settimeout(timeout_s)
        self.size = max(size, _SEQ.size)
        self.seq = 0

    def once(self) -> float:
        self.seq += 1
        payload = _SEQ.pack(self.seq) + bytes(self.size - _SEQ.size)
        t0 = _perf()
        self.sock.send(payload)
        while True:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                raise BenchError(f"UDP echo did not answer ping {self.seq}") from None
            if data[: _SEQ.size] == payload[: _SEQ.size]:
                return _perf() - t0

    def close(self) -> None:
        self.sock.close()


class ZenohPinger:
    """Bare zenoh ping-pong to :func:`workbench.bench.peer.zenoh_echo` (same QoS as the DSP link)."""

    name = "zenoh_pingpong"

    def __init__(
        self,
        session: zenoh.Session,
        ping: str,
        pong: str,
        size: int,
        timeout_s: float = 2.0,
        name: str | None = None,
        prepare: Callable[[], object] | None = None,
    ) -> None:
        if name is not None:
            self.name = name
        self.prepare = prepare
        """Run before each timed round trip, untimed (the work a DSP round trip does between two batches)."""
        self.size = max(size, _SEQ.size)
        self.timeout_s = timeout_s
        # arrival is stamped in zenoh's callback: the figure is the transport's, not our thread hand-off's
        self.inbox: queue.SimpleQueue[tuple[bytes, float]] = queue.SimpleQueue()
        self.pub = _publisher(session, ping)
        self.sub = session.declare_subscriber(pong, lambda s: self.inbox.put((s.payload.to_bytes(), _perf())))
        self.seq = 0

    def connect(self, within_s: float = 15.0) -> None:
        """Ping until the echo answers (the link and its subscription take a moment to appear)."""
        deadline = time.monotonic() + within_s
        while True:
            self.seq += 1
            self.pub.put(_SEQ.pack(self.seq) + bytes(self.size - _SEQ.size))
            try:
                while True:
                    data, _ = self.inbox.get(timeout=0.1)
                    if data[: _SEQ.size] == _SEQ.pack(self.seq):
                        return
            except queue.Empty:
                if time.monotonic() > deadline:
                    raise BenchError(f"zenoh echo did not answer within {within_s:.0f} s") from None

    def once(self) -> float:
        if self.prepare is not None:
            self.prepare()
        self.seq += 1
        head = _SEQ.pack(self.seq)
        payload = head + bytes(self.size - _SEQ.size)
        t0 = _perf()
        self.pub.put(payload)
        while True:
            try:
                data, arrived = self.inbox.get(timeout=self.timeout_s)
            except queue.Empty:
                raise BenchError(f"zenoh echo did not answer ping {self.seq}") from None
            if data[: _SEQ.size] == head:
                return arrived - t0

    def close(self) -> None:
        self.sub.undeclare()
        self.pub.undeclare()


class CanPinger:
    """Bare python-can udp_multicast request/reply to :func:`workbench.bench.peer.can_echo` (8-byte frames)."""

    name = "can_pingpong"

    def __init__(self, bus: can.BusABC, request_id: int = 0x080, reply_id: int = 0x181, timeout_s: float = 2.0) -> None:
        self.bus = bus
        self.request_id = request_id
        self.reply_id = reply_id
        self.timeout_s = timeout_s
        self.seq = 0

    def _round_trip(self, timeout_s: float) -> float | None:
        self.seq += 1
        data = _SEQ.pack(self.seq)
        t0 = _perf()
        self.bus.send(can.Message(arbitration_id=self.request_id, data=data, is_extended_id=False))
        deadline = t0 + timeout_s
        while True:
            remaining = deadline - _perf()
            if remaining <= 0:
                return None
            msg = self.bus.recv(timeout=remaining)
            if msg is not None and msg.arbitration_id == self.reply_id and bytes(msg.data) == data:
                return _perf() - t0

    def connect(self, within_s: float = 10.0) -> None:
        deadline = time.monotonic() + within_s
        while self._round_trip(0.1) is None:
            if time.monotonic() > deadline:
                raise BenchError(f"CAN echo did not answer within {within_s:.0f} s")

    def once(self) -> float:
        rtt = self._round_trip(self.timeout_s)
        if rtt is None:
            raise BenchError(f"CAN echo did not answer request {self.seq}")
        return rtt


class PacedPinger:
    """Another pinger's round trips started ``period_s`` apart, sleeping in
    between, as a real-time loop starts its ticks: the floor for a loop that
    idles between ticks. A back-to-back ping-pong keeps both ends' CPUs and
    caches warm; on this project's VM the bare CAN ping-pong took ~50 µs back
    to back, 140-190 µs started every 1 ms and 360-510 µs every 5 ms
    (docs/benchmarks.md)."""

    def __init__(self, inner: Pinger, period_s: float, clock: Callable[[], float] = time.perf_counter, sleep: Callable[[float], None] = time.sleep) -> None:
        if not period_s > 0:
            raise ValueError(f"period_s must be positive, got {period_s}")
        self.inner = inner
        self.period_s = period_s
        self.name = f"{inner.name} paced"
        self._clock = clock
        self._sleep = sleep
        self._last: float | None = None

    def once(self) -> float:
        if self._last is not None:
            delay = self._last + self.period_s - self._clock()
            if delay > 0:
                self._sleep(delay)
        self._last = self._clock()
        return self.inner.once()


def can_bus(port: int, reply_ids: list[int], channel: str = "239.74.163.2", *, loop_free: bool = True) -> can.BusABC:
    """A udp_multicast bus on a private port that keeps only ``reply_ids``.
    ``loop_free`` (the rig's default transport,
    :class:`service_kit.can_udp.LoopFreeUdpMulticastBus`) never reads its own
    frames back; python-can's stock bus does, and reads and drops them."""
    filters = [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in reply_ids]
    if loop_free:
        return LoopFreeUdpMulticastBus(channel=channel, port=port, hop_limit=0, can_filters=filters)
    return can.Bus(interface="udp_multicast", channel=channel, port=port, hop_limit=0, receive_own_messages=False, can_filters=filters)


# --- through the services --------------------------------------------------------------------


def sample_batch(seq: int, n: int = 20, rate_hz: float = 200.0, seed: int = 0) -> SampleBatch:
    """A 2-in/2-out batch of ``n`` samples, contiguous with batch ``seq - 1``."""
    rng = np.random.default_rng(seed + seq)
    return SampleBatch(
        seq=seq,
        first_tick=seq * n,
        sample_rate_hz=rate_hz,
        sim_time_s=seq * n / rate_hz,
        wall_time_s=time.time(),
        inputs=rng.standard_normal((2, n)),
        outputs=rng.standard_normal((2, n)),
    )


def batch_size_bytes(n: int = 20) -> int:
    return len(encode_batch(sample_batch(0, n)))


def unix_minus_perf(reads: int = 15) -> float:
    """``time.time() - perf_counter()``, from the tightest of ``reads``
    brackets perf, time, perf: a single pair is off by however long the
    thread was pre-empted between its two reads (ms on a loaded host)."""
    best_width, best = math.inf, 0.0
    for _ in range(reads):
        a = _perf()
        unix = time.time()
        b = _perf()
        if b - a < best_width:
            best_width, best = b - a, unix - (a + b) / 2
    return best


class HealthWatch:
    """One service's health messages as they arrive, each with its arrival time, so a caller can
    take the first one after a measurement (e.g. the DSP's, for what only the service itself can
    time, such as its interrupt's put). Health comes once per ``health_period_s``: a few dozen per bench item."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self._latest: queue.SimpleQueue[tuple[bytes, float]] = queue.SimpleQueue()
        self.sub = session.declare_subscriber(key, lambda s: self._latest.put((s.payload.to_bytes(), time.monotonic())))

    def after(self, since: float, timeout_s: float) -> Health | None:
        """The first health message that arrived after ``since`` (``time.monotonic``), waiting
        up to ``timeout_s`` for it; None if none came or it did not decode."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                payload, arrived = self._latest.get(timeout=max(deadline - time.monotonic(), 0.0))
            except queue.Empty:
                return None
            if arrived > since:
                try:
                    return decode(Health, payload)
                except ProtocolError:
                    return None

    def close(self) -> None:
        self.sub.undeclare()


class DspPinger:
    """Acts as the controller against a running DSP service: wait for the
    block to be empty, send a batch, time until its interrupt. As for the
    controller (:meth:`controller.dsp_link.DspLink.on_interrupt`), an
    interrupt flags the block empty for the next batch; an empty flag (the
    board's first, or one an older board sends after each interrupt) is taken
    too. Keeps the DSP's own compute time of every
    step (``Interrupt.compute_time_s``) and splits each round trip at the
    interrupt's construction, from the Unix stamp the interrupt carries
    (``wall_time_s``, set by the DSP right after the step) brought onto this
    process's ``perf_counter``: ``out_s`` = batch put -> interrupt built,
    less the step (transport, the DSP's callback, decode, admission, the
    step's Python glue), ``back_s`` = interrupt built -> its arrival here
    (encode, put, transport); ``out_s + back_s`` is the round trip less the
    step. One host, one clock (to its resolution and any slew since the
    pinger started)."""

    name = "dsp_batch_to_interrupt"

    def __init__(self, session: zenoh.Session, rig_id: str, samples: int = 20, rate_hz: float = 200.0, timeout_s: float = 5.0) -> None:
        keys = Keys(rig_id)
        self.samples = samples
        self.rate_hz = rate_hz
        self.timeout_s = timeout_s
        # arrival is stamped in zenoh's callback, as for ZenohPinger (decoding is not timed)
        self.events: queue.SimpleQueue[tuple[str, bytes, float]] = queue.SimpleQueue()
        self.pub = _publisher(session, keys.batch)
        self.subs = [
            session.declare_subscriber(keys.flag, lambda s: self.events.put(("flag", s.payload.to_bytes(), _perf()))),
            session.declare_subscriber(keys.interrupt, lambda s: self.events.put(("irq", s.payload.to_bytes(), _perf()))),
        ]
        self.seq = 0
        self.empty_for: int | None = None  # next_batch_seq of the latest empty flag seen
        self.compute_s: list[float] = []
        self.out_s: list[float] = []
        self.back_s: list[float] = []
        self.flag_wait_s: list[float] = []
        self._unix_minus_perf = unix_minus_perf()
        self.bad = 0

    def _next(self, deadline: float) -> tuple[str, Any, float] | None:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return None
        try:
            kind, payload, arrived = self.events.get(timeout=remaining)
        except queue.Empty:
            return None
        try:
            return (kind, decode(BlockFlag, payload) if kind == "flag" else decode(Interrupt, payload), arrived)
        except ProtocolError:
            self.bad += 1
            return ("bad", None, arrived)

    def wait_empty(self, timeout_s: float, alive: Callable[[], bool] | None = None) -> None:
        """Wait for the empty flag inviting our next batch (``alive``: give up
        as soon as it says the service has gone)."""
        deadline = time.monotonic() + timeout_s
        while self.empty_for is None or self.empty_for < self.seq:
            event = self._next(min(deadline, time.monotonic() + 0.25))
            if event is None:
                if alive is not None and not alive():
                    raise BenchError(f"the DSP service ended while waiting for the empty flag of batch {self.seq}")
                if time.monotonic() < deadline:
                    continue
                raise BenchError(f"DSP flagged no empty block for batch {self.seq} within {timeout_s:.0f} s")
            kind, msg, _ = event
            if kind == "flag" and msg.state == "empty":
                self.empty_for = max(msg.next_batch_seq, self.empty_for or 0)
                if msg.next_batch_seq > self.seq:
                    self.seq = msg.next_batch_seq  # a DSP that saw batches before us

    def once(self) -> float:
        t_flag = _perf()
        self.wait_empty(self.timeout_s)
        self.flag_wait_s.append(_perf() - t_flag)
        seq = self.seq
        batch = sample_batch(seq, self.samples, self.rate_hz)
        payload = encode_batch(batch)
        deadline = time.monotonic() + self.timeout_s
        t0 = _perf()
        self.pub.put(payload)
        while True:
            event = self._next(deadline)
            if event is None:
                raise BenchError(f"no interrupt for batch {seq} within {self.timeout_s:.0f} s")
            kind, msg, arrived = event
            if kind == "irq" and msg.batch_seq == seq:
                rtt = arrived - t0
                self.empty_for = seq + 1  # the interrupt is the block's empty flag (Fig. 3.5 step 4)
                self.compute_s.append(msg.compute_time_s)
                built = msg.wall_time_s - self._unix_minus_perf  # on this process's perf_counter
                self.out_s.append(built - t0 - msg.compute_time_s)
                self.back_s.append(arrived - built)
                self.seq = seq + 1
                return rtt
            if kind == "flag" and msg.state == "empty":
                self.empty_for = max(msg.next_batch_seq, self.empty_for or 0)

    def close(self) -> None:
        for sub in self.subs:
            sub.undeclare()
        self.pub.undeclare()


class PlantPinger:
    """CANopen master against the plant node: SYNC, wait for TPDO1."""

    name = "plant_sync_to_tpdo"

    def __init__(self, bus: can.BusABC, node_id: int = can_map.DEFAULT_NODE_ID, timeout_s: float = 2.0) -> None:
        self.bus = bus
        self.ids = can_map.cob_ids(node_id)
        self.node_id = node_id
        self.timeout_s = timeout_s
        self.counter = 0
        self.state: can_map.NmtState | None = None

    def _handle(self, msg: can.Message) -> bool:
        """True if ``msg`` is a TPDO1."""
        if msg.arbitration_id == self.ids["heartbeat"] and len(msg.data) == 1:
            try:
                self.state = can_map.decode_heartbeat(msg.data)
            except Exception:
                pass
        return msg.arbitration_id == self.ids["tpdo1"]

    def start(self, within_s: float = 30.0, alive: Callable[[], bool] | None = None) -> None:
        """Wait for the node's heartbeat, NMT start, wait until operational
        (``alive``: give up as soon as it says the node's process has gone)."""
        deadline = time.monotonic() + within_s
        last_start = 0.0
        while self.state != can_map.NmtState.OPERATIONAL:
            now = time.monotonic()
            if alive is not None and not alive():
                raise BenchError(f"the plant process ended before node {self.node_id} became operational")
            if now > deadline:
                raise BenchError(f"plant node {self.node_id} not operational within {within_s:.0f} s (state {self.state})")
            if self.state is not None and now - last_start > 0.5:
                self.bus.send(
                    can.Message(arbitration_id=can_map.NMT_COB_ID, data=can_map.encode_nmt(can_map.NmtCommand.START, self.node_id), is_extended_id=False)
                )
                last_start = now
            msg = self.bus.recv(timeout=0.1)
            if msg is not None:
                self._handle(msg)
        while self.bus.recv(timeout=0.0) is not None:
            pass

    def once(self) -> float:
        self.counter = can_map.next_sync_counter(self.counter)
        frame = can.Message(arbitration_id=can_map.SYNC_COB_ID, data=can_map.encode_sync(self.counter), is_extended_id=False)
        t0 = _perf()
        self.bus.send(frame)
        deadline = t0 + self.timeout_s
        while True:
            remaining = deadline - _perf()
            if remaining <= 0:
                raise BenchError(f"plant sent no TPDO1 for SYNC {self.counter}")
            msg = self.bus.recv(timeout=remaining)
            if msg is not None and self._handle(msg):
                return _perf() - t0
