"""The running rig in Foxglove, live: ``ralf-hil up --live [HOST:]PORT``.

A :class:`LiveView` is a :class:`~workbench.recording.recorder.Mirror` of the
recorder: the recorder's writer thread (fed by the tap, outside the
services) decodes every CAN frame and zenoh message into the recording's
topics and JSON schemas (:mod:`workbench.recording.schemas`) and hands each
record to the view as well as (or instead of) to the MCAP file. So the live
topics, schema names and payloads are the recording's, byte for byte, and
``docs/foxglove-layout.json`` shows either.

What the view adds:

* a ``foxglove-sdk`` WebSocket server (subprotocol ``foxglove.sdk.v1``, the only one
  foxglove-sdk 0.30 accepts: a client offering only the specification's
  ``foxglove.websocket.v1`` is refused with HTTP 400, and the view logs one line naming
  the subprotocol it speaks, :data:`SUBPROTOCOL`)
  on 127.0.0.1 unless another address is given, with the ``time``
  capability: the server's time is the rig's simulated time, and every
  message's timestamp is its simulated time (the SYNC tick of a CAN frame,
  the ``sim_time_s`` of a message);
* its channels before its clients: every topic of the rig
  (:func:`workbench.recording.schemas.rig_topics`) is created before the server
  starts, so a client is advertised only channels that exist on the server's side
  and may subscribe the moment it reads the advertisement. foxglove-sdk 0.30 sends
  a channel created while a client is connected to that client before it enters
  the channel in the client's own table (``ConnectedClient::advertise_channels``):
  a subscription arriving in between is refused ("Unknown channel ID") and never
  retried. A topic outside the rig's list is still created when its first record
  comes, and counted (:attr:`LiveStats.late_channels`);
* decimation: each topic at most ``rate_hz`` messages per second of wall
  time, by the time the tap received them (a browser follows 20 Hz plots;
  the rest is counted as decimated);
* status messages: deadline misses and the controller's last miss, and
  plant events (hard stops, watchdog, payload), as Foxglove status
  notifications.

It never waits: ``Channel.log`` queues each message per client in the SDK,
which keeps at most ``backlog`` messages for a client and drops the oldest
for a slow or stuck one. The SDK counts none of it where a program can read
it: its only trace is a log line, "outbox for client ADDR full", at most one
per 30 s for the whole process (foxglove-sdk 0.30,
``websocket/connected_client/send_lossy.rs``). The view counts those lines
(:attr:`LiveStats.slow_client_notices`, :class:`SdkLogCounter`), and the
clients the SDK disconnects because their control queue (time,
advertisements, statuses) is full: a slow client is seen, the number of
messages it lost is not. The control loop
runs in other processes; the view's cost is its share of the host's CPU
(``ralf-hil measure live``, docs/live-view.md).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import re
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from foxglove.websocket import ServerListener

from service_kit.counters import Counters
from workbench.live.params import ParamPanel

log = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 20.0
DEFAULT_BACKLOG = 256
STATUS_TOPIC_SUFFIXES = ("/controller/status", "/health/controller", "/plant/events")


class LiveViewError(RuntimeError):
    """The view cannot serve (a bad address, a port in use)."""


@dataclass
class LiveStats(Counters):
    """What the view did with the records it was handed."""

    records: int = 0
    published: int = 0
    decimated: int = 0
    """Records not sent because their topic had one within 1/rate_hz s (by design, not loss)."""
    undecodable: int = 0
    statuses: int = 0
    subscriptions: int = 0
    clients_seen: int = 0
    late_channels: int = 0
    """Channels created after the server started (a topic outside the rig's list): a client
    connected then may have had its subscription to it refused."""
    handshakes_refused: int = 0
    """Connections refused in the WebSocket handshake (most often: a client that does not offer
    :data:`SUBPROTOCOL`)."""
    slow_client_notices: int = 0
    """The SDK's "outbox for client ... full" lines: a client fell behind and lost its oldest
    messages (how many, the SDK does not say; at most one line per 30 s per process)."""
    slow_clients_disconnected: int = 0
    """Clients the SDK disconnected because their control queue was full (see :class:`SdkLogCounter`)."""
    slow_clients: int = 0
    """Distinct client addresses among the two above."""
    handoff_dropped: int = 0
    """Items the tap's bounded queue to the recorder's thread refused (that thread fell behind):
    set by whoever closes the recorder."""
    can_socket_drops: int = 0
    """CAN frames the kernel dropped before the tap read them (set likewise)."""
    param_sets_taken: int = 0
    """Parameter changes from the view's clients the controller took (docs/calibration.md)."""
    param_sets_refused: int = 0
    """Parameter changes from the view's clients refused (role, limits, guards, no answer): nothing changed."""


SUBPROTOCOL = "foxglove.sdk.v1"
"""The one WebSocket subprotocol foxglove-sdk 0.30's server accepts (``websocket/handshake.rs``;
no option adds another): the Foxglove protocol under the SDK's name, which recent Foxglove apps
offer beside the specification's ``foxglove.websocket.v1``."""
SDK_LOGGER = "foxglove.websocket"
"""foxglove-sdk's WebSocket server logs here (``foxglove.set_log_level`` routes the SDK's Rust log
to Python's ``logging`` under the Rust module's path)."""
SDK_COUNTED_LOGGERS = ("server", "connected_client.send_lossy", "connected_client.poller")
"""The SDK modules whose INFO lines are counted (clients registered and unregistered; an outbox
full; a connection the client closed); the rest of the SDK's log is not taken."""
_OUTBOX_FULL = re.compile(r"outbox for client (\S+) full")
_REGISTERED = re.compile(r"Registered client (\S+)")
_CLOSED_BY_CLIENT = re.compile(r"Connection closed by client (\S+)")
_UNREGISTERED = re.compile(r"Unregistered client (\S+)")
_HANDSHAKE_FAILED = re.compile(r"Dropping client (\S+): handshake failed")


def handshake_refusal(addr: str) -> str:
    """The one line a refused connection gets on the rig's side."""
    return (
        f"live view: refused client {addr}: its WebSocket handshake did not offer the subprotocol {SUBPROTOCOL}, the only one this server "
        f"speaks (clients offering only foxglove.websocket.v1, such as @foxglove/ws-protocol's default and older Foxglove versions, "
        f"cannot connect; see docs/live-view.md)"
    )


class SdkLogCounter(logging.Handler):
    """Counts into a :class:`LiveStats` what foxglove-sdk 0.30 says only in its log:

    * "outbox for client ADDR full": the client fell behind and its oldest messages were dropped
      (``send_lossy.rs``; at most one line per 30 s for the whole process);
    * "Dropping client ADDR: handshake failed": a connection refused in the WebSocket handshake,
      said as one line naming :data:`SUBPROTOCOL` (:func:`handshake_refusal`) instead;
    * a client unregistered that had not closed the connection itself, while the server runs:
      the SDK disconnected it because its control queue (time, advertisements, statuses; as
      long as the backlog) was full (``ShutdownReason::ControlPlaneQueueFull``, which it does
      not log).

    Warnings and errors go on to this module's logger."""

    def __init__(self, stats: LiveStats) -> None:
        super().__init__(logging.INFO)
        self.stats = stats
        self.stopping = False
        self._slow: set[str] = set()
        self._closed_by_client: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:  # under the handler's own lock (Handler.handle)
        text = record.getMessage()
        if m := _OUTBOX_FULL.search(text):
            self.stats.slow_client_notices += 1
            self._slow_client(m[1])
        elif m := _REGISTERED.search(text):
            self._closed_by_client.discard(m[1])
        elif m := _CLOSED_BY_CLIENT.search(text):
            self._closed_by_client.add(m[1])
        elif (m := _UNREGISTERED.search(text)) and not self.stopping and m[1] not in self._closed_by_client:
            self.stats.slow_clients_disconnected += 1
            self._slow_client(m[1])
        elif m := _HANDSHAKE_FAILED.search(text):
            self.stats.handshakes_refused += 1
            log.warning("%s", handshake_refusal(m[1]))
            return
        if record.levelno >= logging.WARNING:
            log.log(record.levelno, "foxglove-sdk: %s", text)

    def _slow_client(self, addr: str) -> None:
        if addr not in self._slow:
            self._slow.add(addr)
            self.stats.slow_clients += 1


def route_sdk_log() -> logging.Logger:
    """Route the foxglove-sdk log lines :class:`SdkLogCounter` counts to Python's ``logging``,
    without configuring the root logger (the SDK calls ``basicConfig`` when the root has no handler),
    and return the logger of its WebSocket server, which keeps its lines to itself
    (:class:`SdkLogCounter` counts them and passes warnings on). The SDK takes the
    first call of a process only (and ``FOXGLOVE_LOG_LEVEL`` over it), before its first server."""
    import foxglove

    root = logging.getLogger()
    root_has_a_handler = logging.NullHandler()  # so the SDK does not call basicConfig
    root.addHandler(root_has_a_handler)
    try:
        foxglove.set_log_level("INFO")
    finally:
        root.removeHandler(root_has_a_handler)
    logger = logging.getLogger(SDK_LOGGER)
    # Only the counted modules' lines reach Python: each line the SDK logs takes the GIL on
    # the SDK's own thread, which may hold a client's locks meanwhile.
    logger.setLevel(logging.CRITICAL)  # the SDK logs nothing at CRITICAL
    logger.propagate = False  # counted, and said once in the run's summary
    for name in SDK_COUNTED_LOGGERS:
        logging.getLogger(f"{SDK_LOGGER}.{name}").setLevel(logging.INFO)
    return logger


def parse_address(text: str) -> tuple[str, int]:
    """``PORT`` (loopback) or ``HOST:PORT``; a bad one raises :class:`LiveViewError`."""
    host, sep, port_text = text.rpartition(":")
    host = host.strip("[]") if sep else "127.0.0.1"
    try:
        port = int(port_text)
    except ValueError:
        raise LiveViewError(f"--live {text!r}: expected [HOST:]PORT, e.g. 8765 or 0.0.0.0:8765") from None
    if not 0 <= port <= 65535:
        raise LiveViewError(f"--live {text!r}: port {port} is outside 0..65535")
    if host != "localhost":
        try:
            ipaddress.ip_address(host)
        except ValueError:
            raise LiveViewError(f"--live {text!r}: {host!r} is not an IP address (give one, e.g. 127.0.0.1 or 0.0.0.0)") from None
    return host, port


class _Listener(ServerListener):
    """Counts subscriptions and clients (the SDK's ServerListener protocol); with a
    parameter panel (:mod:`workbench.live.params`), answers Foxglove's parameter requests."""

    def __init__(self, stats: LiveStats, params: ParamPanel | None = None) -> None:
        self.stats = stats
        self.params = params
        self._clients: set[int] = set()
        self._lock = threading.Lock()

    def _parameters(self, names: list[str]) -> list[Any]:
        from foxglove.websocket import Parameter

        assert self.params is not None
        return [Parameter(name, value=value) for name, value in self.params.values(names)]

    def on_get_parameters(self, client: Any, param_names: list[str], request_id: str | None = None) -> list[Any]:
        return self._parameters(list(param_names)) if self.params is not None else []

    def on_set_parameters(self, client: Any, parameters: list[Any], request_id: str | None = None) -> list[Any]:
        """Each change through the controller's path (as the tool role); the answer is the table in effect."""
        if self.params is None:
            return []
        for p in parameters:
            if self.params.set(p.name, p.get_value()) is not None:
                self.stats.param_sets_refused += 1
            else:
                self.stats.param_sets_taken += 1
        return self._parameters([p.name for p in parameters])

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self._lock:
            self.stats.subscriptions += 1
            if client.id not in self._clients:
                self._clients.add(client.id)
                self.stats.clients_seen += 1

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        pass


class LiveView:
    """The Foxglove WebSocket server of one rig (see the module doc)."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 8765,
        *,
        rate_hz: float = DEFAULT_RATE_HZ,
        backlog: int = DEFAULT_BACKLOG,
        name: str = "ralf-hil",
        topics: Iterable[tuple[str, Mapping[str, Any]]] = (),
        params: ParamPanel | None = None,
    ) -> None:
        """``topics``: (topic, JSON schema) of every channel to create before the server starts
        (:func:`workbench.recording.schemas.rig_topics`; see the module doc). ``params``: serve
        Foxglove's parameter capability from the controller's table (:mod:`workbench.live.params`)."""
        import foxglove
        from foxglove.websocket import Capability

        if not rate_hz > 0:
            raise LiveViewError(f"live rate must be positive, got {rate_hz}")
        self.stats = LiveStats()
        self.min_interval_s = 1.0 / rate_hz
        self._sdk_log = route_sdk_log()
        self._sdk_counter = SdkLogCounter(self.stats)
        self._sdk_log.addHandler(self._sdk_counter)
        self._foxglove = foxglove
        self._context = foxglove.Context()
        self._channels: dict[str, Any] = {}
        for topic, schema in topics:  # before the server: advertised to each client only as it connects, with the channel in place
            self._channels[topic] = self._new_channel(topic, str(schema["title"]), schema)
        try:
            self.server = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                capabilities=[Capability.Time, *([Capability.Parameters] if params is not None else [])],
                server_listener=_Listener(self.stats, params),
                supported_encodings=["json"],
                context=self._context,
                message_backlog_size=backlog,
            )
        except RuntimeError as exc:
            self._sdk_log.removeHandler(self._sdk_counter)
            raise LiveViewError(f"cannot serve the live view on {host}:{port}: {str(exc).removeprefix('FoxgloveError: ')}") from None
        self.host, self.port = host, int(self.server.port)
        self.params = params
        if params is not None:
            params.on_refused = self._refused
        self._last_sent: dict[str, float] = {}
        self._sim_ns = 0
        self._last_time_broadcast = -1e18
        self._misses = 0
        self._last_miss: str | None = None
        self._closed = False

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    # -- the Mirror API (the recorder's writer thread) ----------------------------------------
    def accept(self, topic: str, log_s: float) -> bool:
        """Decimation: a record of ``topic`` received at wall time ``log_s`` is wanted if the topic
        sent none within 1/rate_hz s before (status topics always: their events are read)."""
        self.stats.records += 1
        if self._closed:
            return False
        if topic.endswith(STATUS_TOPIC_SUFFIXES):
            return True
        if log_s - self._last_sent.get(topic, -1e18) < self.min_interval_s:
            self.stats.decimated += 1
            return False
        self._last_sent[topic] = log_s
        return True

    def on_record(self, topic: str, title: str, schema: Mapping[str, Any], data: bytes, log_s: float) -> None:
        """Publish an accepted record (status topics: read for events, then decimated like the rest)."""
        if self._closed:
            return
        try:
            record = json.loads(data)
        except ValueError:
            self.stats.undecodable += 1
            return
        sim = record.get("sim_time_s") if isinstance(record, dict) else None
        stamp = int(round(sim * 1e9)) if isinstance(sim, int | float) and sim >= 0 else self._sim_ns  # its own time, else the latest
        self._sim_ns = max(self._sim_ns, stamp)
        if topic.endswith(STATUS_TOPIC_SUFFIXES):
            self._status(topic, record)
            if log_s - self._last_sent.get(topic, -1e18) < self.min_interval_s:
                self.stats.decimated += 1
                return
            self._last_sent[topic] = log_s
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._channels[topic] = self._new_channel(topic, title, schema)
            self.stats.late_channels += 1
        channel.log(data, log_time=stamp)
        self.stats.published += 1
        if log_s - self._last_time_broadcast >= self.min_interval_s:
            self._last_time_broadcast = log_s
            self.server.broadcast_time(self._sim_ns)

    def _new_channel(self, topic: str, title: str, schema: Mapping[str, Any]) -> Any:
        schema_obj = self._foxglove.Schema(name=title, encoding="jsonschema", data=json.dumps(schema).encode())
        return self._foxglove.Channel(topic, schema=schema_obj, message_encoding="json", context=self._context)

    def _status(self, topic: str, record: Mapping[str, Any]) -> None:
        from foxglove.websocket import StatusLevel

        t = f"{record.get('sim_time_s', 0.0):.2f} s"
        if topic.endswith("/controller/status"):
            misses = int(record.get("deadline_misses", 0))
            if misses > self._misses:
                self.server.publish_status(f"deadline: {misses} miss(es) so far (+{misses - self._misses}) at {t}", StatusLevel.Warning, "deadline")
                self.stats.statuses += 1
            self._misses = max(self._misses, misses)
        elif topic.endswith("/health/controller"):
            miss = record.get("last_miss")
            if miss and miss != self._last_miss:
                self.server.publish_status(f"deadline: {miss}", StatusLevel.Warning, "last_miss")
                self.stats.statuses += 1
            self._last_miss = miss
        else:
            kind = str(record.get("kind", ""))
            level = StatusLevel.Warning if kind in ("hard_stop", "watchdog") else StatusLevel.Info
            self.server.publish_status(f"plant {kind} at {t}: {record.get('detail', '')}", level, f"plant:{kind}")
            self.stats.statuses += 1

    def _refused(self, reason: str) -> None:
        from foxglove.websocket import StatusLevel

        if not self._closed:
            self.server.publish_status(f"parameter change refused: {reason}", StatusLevel.Warning, "param_refused")
            self.stats.statuses += 1

    def close(self) -> LiveStats:
        if not self._closed:
            self._closed = True
            self._sdk_counter.stopping = True  # from here on every client is unregistered by the stop
            self.server.stop()
            self._sdk_log.removeHandler(self._sdk_counter)
        return self.stats
