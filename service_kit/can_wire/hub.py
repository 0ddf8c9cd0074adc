"""The wire arbiter: one CAN wire for the buses of several processes.

python-can's buses of different processes share nothing but a socket; the
arbiter is the one place that sees every pending frame. Each process's bus
(the python-can interface ``ralfhub``, :mod:`service_kit.can_wire.hub_bus`)
connects to its Unix socket (``SOCK_SEQPACKET``, in the user's private
runtime folder, mode 0600) and hands it every frame it sends. The arbiter
queues the frame on a :class:`~service_kit.can_wire.wire_bus.Wire` (the same
one ``ralfwire`` uses, so the same rule as
:func:`~service_kit.can_wire.arbitration.simulate` without errors): whenever
the wire is idle the pending frames of all clients arbitrate bitwise, the
winner occupies the wire for its exact bits, and when its last EOF bit has
passed it is delivered, stamped with that time, to every connected client
(the sender's own copy marked as such).

- **Transmit order**: each client is one CAN node; by default it offers the
  wire its oldest pending frame (``tx_order="fifo"``: a host's transmit queue,
  as SocketCAN's, so a process's frames keep their order: the controller's
  RPDO1 of a late tick is not overtaken by its next SYNC); ``"priority"``
  offers its highest-priority one (priority-ordered transmit buffers, the
  rule of :func:`~service_kit.can_wire.arbitration.simulate`). Between
  nodes the lowest arbitration field wins either way. A client may choose
  its own order on connect (the restbus sender, standing for many ECUs,
  asks for priority).
- **Clock**: real time by default (the wire's thread waits on
  ``time.monotonic_ns``; delivery = wire time + the host's wake-up latency);
  a :class:`~service_kit.can_wire.wire_bus.ManualWireClock` makes it
  deterministic (tests).
- **Acceptance filters**: a client may set python-can's filters
  (:mod:`service_kit.can_wire.acceptance`, ``can_filters=`` or
  ``set_filters`` on a ``ralfhub`` bus); the arbiter then delivers it only the
  frames they accept, as a CAN controller's filters do, and counts the others
  per client (``clients.filtered`` and ``filtered_per_client``). A client
  without filters gets every frame.
- **Bounded**: at most ``max_clients`` connections (more are refused and
  counted); at most ``max_pending`` frames of one client waiting for the wire
  (more are refused and counted: a CAN controller's transmit buffers are
  full); deliveries a client does not read wait in its outbox of at most
  ``max_outbox`` packets, beyond which its oldest are dropped and counted
  (a CAN controller's receive FIFO overrun: a process busy elsewhere, such
  as a service compiling its kernels at start-up, loses frames, not its bus).
  A client that vanishes is dropped and counted, its frames still waiting
  for the wire with it; a packet that is not a frame is junk, counted and
  dropped (:mod:`service_kit.can_wire.hub_protocol`).
- **Bus load** (:class:`HubStats`): busy share overall and per window
  (frames never overlap on the wire: each window's busy time is the sum of
  the frames' parts in it),
  frames/s, bits/s, per-identifier queuing delay (received by the arbiter
  to SOF), and SYNC→TPDO1 (last EOF bit to last EOF bit) against its
  physical floor (the intermission after SYNC plus TPDO1's bits to EOF).

``python -m service_kit.can_wire.hub --socket PATH --bitrate 1000000
[--stats FILE] [--live FILE --live-period-s 1]`` runs one until SIGTERM/SIGINT
(or until the launcher named by ``RALF_LAUNCHER_PID`` ends) and writes its
figures to the stats FILE as JSON; ``--live`` rewrites its FILE with the
figures of each period while it runs (:mod:`service_kit.can_wire.hub_live`).
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import selectors
import socket
import stat
import sys
import threading
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import can

from service_kit.can_wire import hub_protocol as proto
from service_kit.can_wire.acceptance import Filter, accepts
from service_kit.can_wire.arbitration import INTERMISSION_BITS
from service_kit.can_wire.bits import FrameBits, frame_of_message
from service_kit.can_wire.bus_load import delay_stats
from service_kit.can_wire.timing import NS_PER_S, bit_time_ns
from service_kit.can_wire.wire_bus import RealTimeWireClock, Wire, WireNode, _InFlight

SYNC_ID = 0x080
TPDO1_ID = 0x181
"""The rig's SYNC and its plant's TPDO1 (``protocol/ralf.dbc``)."""
UNIX_PATH_MAX = 107
"""Longest Unix socket path Linux takes (108 bytes with the terminating zero)."""


class HubError(Exception):
    """The arbiter cannot start (one line)."""


class Endpoint(Protocol):
    """A connected bus as the arbiter sees it."""

    _open: bool
    in_wire: int
    receive_own: bool
    filters: tuple[Filter, ...] | None

    def put(self, packet: bytes) -> None: ...


@dataclass
class HubStats:
    """The arbiter's figures (module docstring). Running totals cover the
    whole run; windows, percentiles and SYNC→TPDO1 cover the last ``keep``
    deliveries (bounded memory)."""

    bitrate: int
    window_ns: int = 100_000_000
    keep: int = 200_000
    sync_id: int = SYNC_ID
    tpdo_id: int = TPDO1_ID
    frames: int = 0
    bits: int = 0
    busy_ns: int = 0
    first_start_ns: int | None = None
    last_end_ns: int = 0
    recent: deque[tuple[int, int, int, int, int]] = field(default_factory=deque)
    """(id, queued, start, end, bits) of the last ``keep`` deliveries."""
    sync_to_tpdo_ns: deque[int] = field(default_factory=deque)
    sync_to_tpdo_floor_margin_min_ns: int | None = None
    """Smallest SYNC→TPDO1 less its physical floor (never negative on a wire)."""
    sync_to_tpdo_margin_ns: deque[int] = field(default_factory=deque)
    """Each of :attr:`sync_to_tpdo_ns` less its physical floor."""
    sync_to_tpdo_total: int = 0
    """SYNC→TPDO1 pairs over the whole run (the deques keep the last ``keep``)."""
    _last_sync_bit_ns: int | None = None
    max_windows: int = 36_000
    """Windows kept for the peak (an hour of 100 ms windows)."""
    _windows: dict[int, int] = field(default_factory=dict)
    """Busy ns per window index since the first frame (frames never overlap on the wire)."""

    def __post_init__(self) -> None:
        self.recent = deque(maxlen=self.keep)
        self.sync_to_tpdo_ns = deque(maxlen=self.keep)
        self.sync_to_tpdo_margin_ns = deque(maxlen=self.keep)

    def _add_busy(self, start_ns: int, end_ns: int) -> None:
        origin = self.first_start_ns or 0
        s, e = start_ns - origin, end_ns - origin
        while s < e:
            i = s // self.window_ns
            b = min(e, (i + 1) * self.window_ns)
            self._windows[i] = self._windows.get(i, 0) + b - s
            s = b
        while len(self._windows) > self.max_windows:
            del self._windows[next(iter(self._windows))]

    def add(self, frame: FrameBits, queued_ns: int, start_ns: int, last_bit_ns: int, end_ns: int) -> None:
        self.frames += 1
        self.bits += frame.n_bits
        self.busy_ns += end_ns - start_ns
        if self.first_start_ns is None:
            self.first_start_ns = start_ns
        self.last_end_ns = max(self.last_end_ns, end_ns)
        self._add_busy(start_ns, end_ns)
        self.recent.append((frame.arbitration_id, queued_ns, start_ns, end_ns, frame.n_bits))
        if frame.extended:
            return
        if frame.arbitration_id == self.sync_id:
            self._last_sync_bit_ns = last_bit_ns
        elif frame.arbitration_id == self.tpdo_id and self._last_sync_bit_ns is not None:
            delta = last_bit_ns - self._last_sync_bit_ns
            floor = (INTERMISSION_BITS + frame.n_bits_to_eof) * bit_time_ns(self.bitrate)
            self.sync_to_tpdo_ns.append(delta)
            margin = delta - floor
            self.sync_to_tpdo_margin_ns.append(margin)
            self.sync_to_tpdo_total += 1
            if self.sync_to_tpdo_floor_margin_min_ns is None or margin < self.sync_to_tpdo_floor_margin_min_ns:
                self.sync_to_tpdo_floor_margin_min_ns = margin
            self._last_sync_bit_ns = None  # one TPDO1 per SYNC

    def report(self) -> dict[str, Any]:
        """The figures as JSON-ready numbers (µs for delays)."""
        span = self.last_end_ns - self.first_start_ns if self.first_start_ns is not None else 0
        out: dict[str, Any] = {
            "bitrate": self.bitrate,
            "frames": self.frames,
            "bits": self.bits,
            "span_s": span / NS_PER_S,
            "busy_pct": 100 * self.busy_ns / span if span > 0 else 0.0,
            "frames_per_s": self.frames * NS_PER_S / span if span > 0 else 0.0,
            "bits_per_s": self.bits * NS_PER_S / span if span > 0 else 0.0,
            "window_ms": self.window_ns / 1e6,
        }
        if self._windows:
            last = max(self._windows)
            full = [busy for i, busy in self._windows.items() if i != last]  # the last is cut short by the end
            out["peak_window_busy_pct"] = 100 * max(full) / self.window_ns if full else out["busy_pct"]
            out["windows"] = last + 1
        if self.recent:
            by_id: dict[int, list[int]] = {}
            for ident, q, s, _e, _bits in self.recent:
                by_id.setdefault(ident, []).append(s - q)
            out["queuing_delay_us"] = {
                f"0x{ident:03X}": {"n": d.n, "mean": d.mean_ns / 1e3, "p50": d.p50_ns / 1e3, "p99": d.p99_ns / 1e3, "max": d.max_ns / 1e3}
                for ident, d in delay_stats(by_id).items()
            }
        if self.sync_to_tpdo_ns:
            st = delay_stats({0: list(self.sync_to_tpdo_ns)})[0]
            out["sync_to_tpdo1_us"] = {
                "n": st.n,
                "min": min(self.sync_to_tpdo_ns) / 1e3,
                "p50": st.p50_ns / 1e3,
                "p99": st.p99_ns / 1e3,
                "max": st.max_ns / 1e3,
            }
            out["sync_to_tpdo1_floor_margin_min_us"] = (self.sync_to_tpdo_floor_margin_min_ns or 0) / 1e3
        return out


class HubWire(Wire):
    """The :class:`~service_kit.can_wire.wire_bus.Wire` of the arbiter: its
    deliveries go to :attr:`on_delivery` and into :attr:`stats`. A frame whose
    sender vanished while it was on the wire is still delivered (it was sent)."""

    stats: HubStats
    on_delivery: Any

    def _deliver(self, flight: _InFlight) -> None:
        item = flight.item
        item.sender.in_wire -= 1  # type: ignore[attr-defined]
        self.stats.add(item.frame, item.queued_ns, flight.start_ns, flight.last_bit_ns, flight.end_ns)
        msg = copy.copy(item.msg)
        msg.timestamp = self.clock.timestamp(flight.last_bit_ns)
        self.on_delivery(item.sender, msg, flight.last_bit_ns)


TX_ORDERS = ("fifo", "priority")


def make_wire(bitrate: int, clock: Any, stats: HubStats, on_delivery: Any, *, tx_order: str = "fifo", channel: str = "hub") -> HubWire:
    if tx_order not in TX_ORDERS:
        raise ValueError(f"transmit order {tx_order!r} is none of {', '.join(TX_ORDERS)}")
    wire = HubWire.__new__(HubWire)
    wire.stats = stats
    wire.on_delivery = on_delivery
    HubWire.__init__(wire, channel, bitrate, clock, fifo_per_sender=tx_order == "fifo")  # the real-time thread starts here, with stats in place
    return wire


@dataclass
class HubCounters:
    connected: int = 0
    """Clients that connected over the run."""
    vanished: int = 0
    """Clients that went away (closed, died) and were dropped."""
    overruns: int = 0
    """Deliveries dropped, oldest first, from the outbox of a client that did not read them."""
    refused_clients: int = 0
    junk: int = 0
    """Packets that were not a frame: counted and dropped."""
    refused_frames: int = 0
    """Frames refused: the client had ``max_pending`` frames waiting, or the frame has no classical layout."""
    filtered: int = 0
    """Deliveries not made because the client's acceptance filters refused the frame (all clients)."""


class Hub:
    """The arbiter's core (module docstring), without sockets: endpoints
    :meth:`attach`, :meth:`submit` frames and receive packets through
    their ``put``. :class:`HubServer` adds the socket."""

    def __init__(
        self,
        bitrate: int,
        *,
        clock: Any = None,
        max_pending: int = 256,
        window_ns: int = 100_000_000,
        keep: int = 200_000,
        sync_id: int = SYNC_ID,
        tpdo_id: int = TPDO1_ID,
        tx_order: str = "fifo",
    ) -> None:
        bit_time_ns(bitrate)  # ValueError for a bit rate the wire does not model
        self.bitrate = bitrate
        self.max_pending = max_pending
        self.counters = HubCounters()
        self.stats = HubStats(bitrate, window_ns=window_ns, keep=keep, sync_id=sync_id, tpdo_id=tpdo_id)
        self._lock = threading.Lock()
        self._endpoints: list[Endpoint] = []
        self._nodes: dict[int, WireNode] = {}
        """Each connected bus's CAN node on the wire (its error counters and state)."""
        self._names: dict[int, str] = {}
        self.filtered_per_client: dict[str, int] = {}
        """Deliveries its filters refused, by client (``client-N``, N in connection order; only clients that filtered)."""
        self.wire = make_wire(bitrate, clock if clock is not None else RealTimeWireClock(), self.stats, self._broadcast, tx_order=tx_order)

    def attach(self, endpoint: Endpoint) -> None:
        with self._lock:
            self._endpoints.append(endpoint)
            self.counters.connected += 1
            name = f"client-{self.counters.connected}"
            self._names[id(endpoint)] = name
            self._nodes[id(endpoint)] = self.wire.add_node(name)

    def detach(self, endpoint: Endpoint) -> None:
        endpoint._open = False
        with self._lock:
            if endpoint in self._endpoints:
                self._endpoints.remove(endpoint)
            node = self._nodes.pop(id(endpoint), None)
            self._names.pop(id(endpoint), None)
        if node is not None:
            self.wire.remove_node(node)

    @property
    def n_clients(self) -> int:
        with self._lock:
            return len(self._endpoints)

    def submit(self, endpoint: Endpoint, msg: can.Message) -> bool:
        """Queues ``msg`` on the wire at the clock's now; False (counted) when refused."""
        if endpoint.in_wire >= self.max_pending:
            self.counters.refused_frames += 1
            return False
        try:
            frame = frame_of_message(msg)
        except ValueError:
            self.counters.refused_frames += 1
            return False
        with self._lock:
            node = self._nodes.get(id(endpoint))
        if node is None:  # not attached, or gone
            self.counters.refused_frames += 1
            return False
        endpoint.in_wire += 1
        self.wire.submit(endpoint, msg, frame, node)  # type: ignore[arg-type]
        return True

    def _broadcast(self, sender: Endpoint, msg: can.Message, last_bit_ns: int) -> None:
        with self._lock:
            endpoints = [(ep, self._names.get(id(ep), "")) for ep in self._endpoints]
        packet: bytes | None = None  # encoded once, and only if some client takes it
        ident, extended = msg.arbitration_id, msg.is_extended_id
        for ep, name in endpoints:
            if not ep._open or (ep is sender and not ep.receive_own):
                continue
            if not accepts(ep.filters, ident, extended):
                self.counters.filtered += 1
                self.filtered_per_client[name] = self.filtered_per_client.get(name, 0) + 1
                continue
            if ep is sender:
                ep.put(proto.encode_delivery(msg, last_bit_ns, True))
                continue
            if packet is None:
                packet = proto.encode_delivery(msg, last_bit_ns, False)
            ep.put(packet)

    def report(self) -> dict[str, Any]:
        out = self.stats.report()
        out["clients"] = {**self.counters.__dict__, "frames_dropped": self.wire.dropped}
        out["filtered_per_client"] = dict(self.filtered_per_client)
        return out

    def close(self) -> None:
        self.wire.close()


class _SocketClient:
    """One connected bus: its socket and its outbox of deliveries not yet taken."""

    def __init__(self, sock: socket.socket, max_outbox: int, counters: HubCounters) -> None:
        self.sock = sock
        self.counters = counters
        self._open = True
        self.in_wire = 0
        self.receive_own = True
        self.filters: tuple[Filter, ...] | None = None
        """Its acceptance filters (None: every frame)."""
        self.fifo = True
        """Offers the wire its oldest frame (False: its highest-priority one)."""
        self.gone = False
        """Set by any thread when the client went away; the I/O thread closes it."""
        self.outbox: deque[bytes] = deque()
        self.max_outbox = max_outbox
        self.lock = threading.Lock()

    def put(self, packet: bytes) -> None:
        with self.lock:
            if self.gone:
                return
            if not self.outbox:
                try:
                    self.sock.send(packet)
                    return
                except BlockingIOError:
                    pass
                except OSError:
                    self.gone, self._open = True, False
                    return
            if len(self.outbox) >= self.max_outbox:
                self.outbox.popleft()
                self.counters.overruns += 1
            self.outbox.append(packet)

    def flush(self) -> None:
        with self.lock:
            while self.outbox and not self.gone:
                try:
                    self.sock.send(self.outbox[0])
                except BlockingIOError:
                    return
                except OSError:
                    self.gone, self._open = True, False
                    return
                self.outbox.popleft()


def check_socket_path(path: Path) -> None:
    """HubError unless ``path`` can be the arbiter's socket: short enough, in a folder of
    this user that nobody else may enter or write, and not in use."""
    if len(os.fsencode(str(path))) > UNIX_PATH_MAX:
        raise HubError(f"{path}: longer than the {UNIX_PATH_MAX} bytes a Unix socket path may have")
    folder = path.parent
    try:
        st = os.stat(folder)
    except OSError as exc:
        raise HubError(f"{folder}: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise HubError(f"{folder}: not a folder of this user closed to others' writes: the socket would not be private")
    if os.path.lexists(path):
        raise HubError(f"{path}: exists already (another arbiter, or a leftover)")


MAX_READS_PER_WAKE = 64
"""Packets read from one client before the others' turn (and new connections')."""


class HubServer:
    """A :class:`Hub` behind a Unix ``SOCK_SEQPACKET`` socket at ``path``
    (mode 0600), served by a thread of its own (:meth:`start`)."""

    def __init__(self, path: Path | str, bitrate: int, *, clock: Any = None, max_clients: int = 64, max_outbox: int = 4096, **hub_options: Any) -> None:
        self.path = Path(path)
        check_socket_path(self.path)
        self.hub = Hub(bitrate, clock=clock, **hub_options)
        self.max_clients = max_clients
        self.max_outbox = max_outbox
        self._listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        old = os.umask(0o177)
        try:
            self._listener.bind(str(self.path))
        except OSError as exc:
            self._listener.close()
            self.hub.close()
            raise HubError(f"{self.path}: cannot listen ({exc.strerror or exc})") from None
        finally:
            os.umask(old)
        os.chmod(self.path, 0o600)
        self._listener.listen(max_clients)
        self._listener.setblocking(False)
        self._wake_r, self._wake_w = os.pipe()
        self._clients: list[_SocketClient] = []
        self._closed = False
        self._thread: threading.Thread | None = None

    def start(self) -> HubServer:
        self._thread = threading.Thread(target=self._serve, name="can-wire-hub", daemon=True)
        self._thread.start()
        return self

    def _accept(self, sel: selectors.BaseSelector) -> None:
        while True:
            try:
                sock, _ = self._listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            if len(self._clients) >= self.max_clients:
                self.hub.counters.refused_clients += 1
                sock.close()
                continue
            sock.setblocking(False)
            client = _SocketClient(sock, self.max_outbox, self.hub.counters)
            client.fifo = self.hub.wire.fifo_per_sender
            try:
                sock.send(proto.encode_hello(self.hub.bitrate))
            except OSError:
                sock.close()
                self.hub.counters.vanished += 1
                continue
            self._clients.append(client)
            sel.register(sock, selectors.EVENT_READ, client)
            self.hub.attach(client)

    def _read(self, client: _SocketClient) -> None:
        for _ in range(MAX_READS_PER_WAKE):  # the rest on the next round: a flooding client must not starve the others
            if client.gone:
                return
            try:
                packet = client.sock.recv(proto.MAX_PACKET)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                client.gone, client._open = True, False
                return
            if not packet:
                client.gone, client._open = True, False
                return
            msg = proto.decode_send(packet)
            if msg is None and (options := proto.decode_options(packet)) is not None:
                client.receive_own, order = options
                if order is not None:
                    client.fifo = order == "fifo"
                continue
            if msg is None and (filters := proto.decode_filters(packet)) is not None:
                client.filters = filters[0]
                continue
            if msg is None:
                self.hub.counters.junk += 1
                continue
            self.hub.submit(client, msg)

    def _drop(self, client: _SocketClient, sel: selectors.BaseSelector) -> None:
        self.hub.detach(client)
        self.hub.counters.vanished += 1
        sel.unregister(client.sock)
        client.sock.close()
        self._clients.remove(client)

    def _serve(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self._listener, selectors.EVENT_READ, "listen")
        sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        try:
            while not self._closed:
                waiting = any(c.outbox for c in self._clients)
                for key, _ in sel.select(timeout=0.005 if waiting else 0.1):
                    if key.data == "listen":
                        self._accept(sel)
                    elif key.data == "wake":
                        return
                    else:
                        self._read(key.data)
                for client in list(self._clients):
                    client.flush()
                    if client.gone:
                        self._drop(client, sel)
        finally:
            for client in list(self._clients):
                sel.unregister(client.sock)
                client.sock.close()
            sel.close()

    def report(self) -> dict[str, Any]:
        return self.hub.report()

    def close(self) -> dict[str, Any]:
        """Stops serving, closes every connection and removes the socket; the final figures."""
        if not self._closed:
            self._closed = True
            os.write(self._wake_w, b"x")
            if self._thread is not None:
                self._thread.join(timeout=5)
            self._listener.close()
            self.hub.close()
            os.close(self._wake_r)
            os.close(self._wake_w)
            try:
                self.path.unlink()
            except OSError:
                pass
        return self.report()


def main(argv: list[str] | None = None) -> int:
    from service_kit.runtime import follow_launcher, stop_on_signals

    parser = argparse.ArgumentParser(prog="python -m service_kit.can_wire.hub", description="One CAN wire for the buses of several processes.")
    parser.add_argument("--socket", required=True, type=Path, help="the Unix socket to listen on (its folder private to this user)")
    parser.add_argument("--bitrate", required=True, type=int, help="bit/s")
    parser.add_argument("--stats", type=Path, default=None, help="write the figures to this JSON file on exit")
    parser.add_argument("--live", type=Path, default=None, help="rewrite this JSON file with the last period's figures every period")
    parser.add_argument("--live-period-s", type=float, default=1.0, help="the period of --live (default %(default)s s)")
    parser.add_argument("--window-ms", type=float, default=100.0, help="bus load window (default %(default)s ms)")
    parser.add_argument(
        "--tx-order", choices=TX_ORDERS, default="fifo", help="what each client offers the wire: its oldest frame (default) or its highest-priority one"
    )
    args = parser.parse_args(argv)
    stop, _received = stop_on_signals(say=False)
    sys.setswitchinterval(0.0005)  # the wire's thread waits for frames' ends: hand it the interpreter soon
    try:
        server = HubServer(args.socket, args.bitrate, window_ns=round(args.window_ms * 1e6), tx_order=args.tx_order).start()
    except (HubError, ValueError) as exc:
        print(f"can wire hub: {exc}", file=sys.stderr)
        return 2
    if args.live_period_s <= 0:
        print(f"can wire hub: --live-period-s {args.live_period_s:g} is not a positive number of seconds", file=sys.stderr)
        server.close()
        return 2
    follow_launcher(int(os.environ.get("RALF_LAUNCHER_PID", "0") or 0), stop)
    if args.live is not None:
        from service_kit.can_wire.hub_live import publish_periodically

        threading.Thread(target=publish_periodically, args=(server.hub, args.live, args.live_period_s, stop), name="can-wire-live", daemon=True).start()
    print(f"can wire hub: {args.socket} at {args.bitrate} bit/s", flush=True)
    stop.wait()
    report = server.close()
    if args.stats is not None:
        tmp = args.stats.with_name(args.stats.name + ".part")
        tmp.write_text(json.dumps(report, indent=2))
        tmp.replace(args.stats)
    c = report["clients"]
    print(
        f"can wire hub: {report['frames']} frames, busy {report['busy_pct']:.1f} %, {c['connected']} clients, "
        f"{c['vanished']} vanished, {c['overruns']} deliveries overrun, {c['junk']} junk packets, {c['refused_frames']} frames refused, {c['filtered']} deliveries filtered",
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
