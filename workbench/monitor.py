"""``ralf-hil monitor``: a live view of one rig on zenoh.

Shows every service's health (``ralf/<rig>/health/*``: state, counters,
latency percentiles, last miss), its liveliness (``ralf/<rig>/alive/*``: up
or lost, since when) and the controller's status. Connects like the
services do: ``RALF_ZENOH_*`` variables (:class:`protocol.settings.CommonSettings`),
with ``--rig-id`` and ``--connect`` taking precedence. ``--once`` collects
for a short window, prints one snapshot and exits.

:class:`RigWatch` is the collector; the bench uses it too.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

import zenoh
from rich.console import Console, Group, RenderableType
from rich.table import Table
from rich.text import Text

from protocol.errors import ConfigError, ProtocolError
from protocol.keys import SERVICES, Keys
from protocol.messages import ControllerStatus, Health, decode
from protocol.settings import CommonSettings, load_settings
from service_kit.transport import zenoh_config, zenoh_error_text
from service_kit.zenoh_log import init_zenoh_log


def health_key_service(key: str) -> str:
    """The service a health sample is filed under: its key's last chunk
    (``ralf/<rig>/health/<service>``), which the access rules let only that
    service publish on, never the ``service`` the payload claims."""
    return key.rsplit("/", 1)[-1]


class RigWatch:
    """Subscribes to one rig's health, liveliness and controller status.

    Callbacks run on zenoh's threads and only decode and store, under a
    lock; :meth:`snapshot` gives a JSON-ready copy. With ``history`` every
    controller status is kept with its arrival time (``time.monotonic()``).
    Health is filed by the key it arrived on; a payload naming another
    service is refused and counted (``health_refused``).
    """

    def __init__(self, rig_id: str, config: zenoh.Config, history: bool = False) -> None:
        self.keys = Keys(rig_id)
        self.rig_id = rig_id
        self.started_wall = time.time()
        self._lock = threading.Lock()
        self.health: dict[str, Health] = {}
        self.health_at: dict[str, float] = {}
        self.alive: dict[str, dict[str, Any]] = {}
        self.events: list[dict[str, Any]] = []
        self.status: ControllerStatus | None = None
        self.status_at: float | None = None
        self.keep_history = history
        self.status_history: list[tuple[float, ControllerStatus]] = []
        self.bad_messages = 0
        self.health_refused = 0
        self.messages = 0
        init_zenoh_log()
        self.session = zenoh.open(config)
        try:
            self._subs = [
                self.session.declare_subscriber(self.keys.health_all, self._on_health),
                self.session.declare_subscriber(self.keys.controller_status, self._on_status),
                self.session.liveliness().declare_subscriber(self.keys.alive_all, self._on_alive, history=True),
            ]
        except Exception:
            self.session.close()
            raise

    # -- callbacks (zenoh threads) ---------------------------------------------------------
    def _on_health(self, sample: zenoh.Sample) -> None:
        try:
            health = decode(Health, sample.payload.to_bytes())
        except ProtocolError:
            with self._lock:
                self.bad_messages += 1
            return
        service = health_key_service(str(sample.key_expr))
        with self._lock:
            if health.service != service:
                self.health_refused += 1
                return
            self.messages += 1
            self.health[service] = health
            self.health_at[service] = time.time()

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            status = decode(ControllerStatus, sample.payload.to_bytes())
        except ProtocolError:
            with self._lock:
                self.bad_messages += 1
            return
        now = time.time()
        with self._lock:
            self.messages += 1
            self.status = status
            self.status_at = now
            if self.keep_history:
                self.status_history.append((time.monotonic(), status))

    def _on_alive(self, sample: zenoh.Sample) -> None:
        service = str(sample.key_expr).rsplit("/", 1)[-1]
        up = sample.kind == zenoh.SampleKind.PUT
        now = time.time()
        with self._lock:
            self.messages += 1
            entry = self.alive.get(service)
            if entry is None or entry["up"] != up:
                self.alive[service] = {"up": up, "since": now, "changes": (entry["changes"] + 1) if entry else 1}
                self.events.append({"time": now, "service": service, "event": "up" if up else "lost"})

    # -- reading -------------------------------------------------------------------------------
    def history(self) -> list[tuple[float, ControllerStatus]]:
        """The controller statuses seen so far with their arrival times (needs ``history=True``)."""
        with self._lock:
            return list(self.status_history)

    def snapshot(self) -> dict[str, Any]:
        """Everything seen so far, as plain JSON-ready data (times are Unix seconds)."""
        now = time.time()
        with self._lock:
            names = list(SERVICES) + sorted((set(self.health) | set(self.alive)) - set(SERVICES))
            services: dict[str, Any] = {}
            for name in names:
                alive = self.alive.get(name)
                health = self.health.get(name)
                services[name] = {
                    "alive": "unknown" if alive is None else ("up" if alive["up"] else "lost"),
                    "alive_since": alive["since"] if alive else None,
                    "alive_changes": alive["changes"] if alive else 0,
                    "health": health.model_dump(mode="json") if health else None,
                    "health_age_s": (now - self.health_at[name]) if name in self.health_at else None,
                }
            return {
                "rig_id": self.rig_id,
                "taken_at": now,
                "watching_for_s": now - self.started_wall,
                "services": services,
                "controller": self.status.model_dump(mode="json") if self.status else None,
                "status_age_s": (now - self.status_at) if self.status_at is not None else None,
                "events": list(self.events),
                "messages": self.messages,
                "bad_messages": self.bad_messages,
                "health_refused": self.health_refused,
            }

    def close(self) -> None:
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:
                pass
        self.session.close()

    def __enter__(self) -> RigWatch:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- settings -----------------------------------------------------------------------------------


def monitor_settings(rig_id: str | None = None, connect: str | None = None) -> CommonSettings:
    """``RALF_*`` settings with the command line on top; raises :class:`ConfigError`."""
    overrides: dict[str, Any] = {}
    if rig_id is not None:
        overrides["rig_id"] = rig_id
    if connect is not None:
        overrides["zenoh_connect"] = connect
    settings: CommonSettings = load_settings(CommonSettings, overrides)
    if settings.zenoh_mode != "router" and not settings.zenoh_multicast_scouting and not settings.endpoints("connect") and not settings.endpoints("listen"):
        raise ConfigError(
            "no zenoh endpoint: multicast scouting is off, so the monitor needs --connect ENDPOINT[,ENDPOINT...] "
            "(e.g. the tls/127.0.0.1:PORT that `ralf-hil up` prints; its tool.env sets RALF_ZENOH_CONNECT), RALF_ZENOH_CONNECT, RALF_ZENOH_LISTEN, "
            "or RALF_ZENOH_MULTICAST_SCOUTING=true"
        )
    return settings


def open_watch(settings: CommonSettings, history: bool = False) -> RigWatch:
    return RigWatch(settings.rig_id, zenoh_config(settings), history=history)


def snapshot_once(
    rig_id: str | None = None, connect: str | Sequence[str] | None = None, window_s: float = 2.5, settings: CommonSettings | None = None
) -> dict[str, Any]:
    """Collect for ``window_s`` seconds and return one snapshot (the session is closed)."""
    if settings is None:
        text = connect if isinstance(connect, str) or connect is None else ",".join(connect)
        settings = monitor_settings(rig_id, text)
    with open_watch(settings) as watch:
        time.sleep(window_s)
        snap = watch.snapshot()
    snap["window_s"] = window_s
    return snap


# --- rendering ----------------------------------------------------------------------------------


def _clock(ts: float | None) -> str:
    return time.strftime("%H:%M:%S", time.localtime(ts)) if ts else "–"


def _ms(seconds: float) -> str:
    ms = seconds * 1e3
    return f"{ms:.3f}" if ms < 10 else f"{ms:.1f}"


def _counters(counters: dict[str, int]) -> str:
    nonzero = [f"{k}={v}" for k, v in counters.items() if v]
    zero = sum(1 for v in counters.values() if not v)
    text = ", ".join(nonzero)
    if zero:
        text += f"{', ' if text else ''}({zero} more at 0)"
    return text or "–"


_STATE_STYLE = {"running": "green", "degraded": "yellow", "starting": "cyan", "stopping": "cyan", "failed": "red"}


def render(snap: dict[str, Any]) -> RenderableType:
    """The snapshot as rich tables: services, latencies, controller status, recent events."""
    services = Table(title=f"rig {snap['rig_id']}  ({_clock(snap['taken_at'])})", expand=False)
    for col in ("service", "alive since", "state", "health", "sim time"):
        services.add_column(col, no_wrap=True)
    services.add_column("last miss", overflow="fold", min_width=12)
    counters = Table(title="counters", show_header=False)
    counters.add_column("service", no_wrap=True)
    counters.add_column("counters", overflow="fold")
    latencies = Table(title="latencies (ms)")
    for col in ("service", "latency", "n", "p50", "p99", "p99.9", "max"):
        latencies.add_column(col, justify="left" if col in ("service", "latency") else "right", no_wrap=True)
    for name, svc in snap["services"].items():
        alive = svc["alive"]
        alive_text = Text(alive + (f" {_clock(svc['alive_since'])}" if svc["alive_since"] else ""), style={"up": "green", "lost": "red"}.get(alive, "dim"))
        health = svc["health"]
        if health is None:
            services.add_row(name, alive_text, Text("no health yet", style="dim"), "–", "–", "–")
            continue
        age = svc["health_age_s"]
        services.add_row(
            name,
            alive_text,
            Text(health["state"], style=_STATE_STYLE.get(health["state"], "")),
            f"#{health['seq']} ({age:.1f} s)" if age is not None else f"#{health['seq']}",
            f"{health['sim_time_s']:.2f} s",
            health["last_miss"] or "–",
        )
        counters.add_row(name, _counters(health["counters"]))
        for lname, stats in health["latencies"].items():
            latencies.add_row(name, lname, str(stats["count"]), _ms(stats["p50"]), _ms(stats["p99"]), _ms(stats["p999"]), _ms(stats["max"]))
    parts: list[RenderableType] = [services]
    if counters.row_count:
        parts.append(counters)
    if latencies.row_count:
        parts.append(latencies)
    c = snap["controller"]
    if c is None:
        parts.append(Text("controller status: none yet", style="dim"))
    else:
        freq = f"{c['latest_frequency_hz']:.3f} Hz" if c.get("latest_frequency_hz") else "–"
        parts.append(
            Text(
                f"controller: sim {c['sim_time_s']:.2f} s | ticks {c['ticks']} | loop {c['loop_rate_hz']:.1f} Hz | "
                f"batches {c['batches_sent']} | interrupts {c['interrupts']} | f1 {freq} | "
                f"deadline misses {c['deadline_misses']} | overruns {c['overruns']}{' | finished' if c['finished'] else ''}"
            )
        )
    if snap["events"]:
        recent = snap["events"][-6:]
        parts.append(Text("liveliness: " + "; ".join(f"{_clock(e['time'])} {e['service']} {e['event']}" for e in recent)))
    if snap["bad_messages"]:
        parts.append(Text(f"undecodable messages: {snap['bad_messages']}", style="yellow"))
    if snap.get("health_refused"):
        parts.append(Text(f"health refused (payload names another service than its key): {snap['health_refused']}", style="yellow"))
    return Group(*parts)


# --- command ------------------------------------------------------------------------------------


def credentials_hint(settings: Any) -> str:
    """Why a tool may hear nothing from a running rig: its credentials. A
    rig started by ``ralf-hil up`` links only to sessions holding a
    certificate of the run's own authority and applies access rules; a
    tool without one is not told, it just hears nothing."""
    tls = settings.zenoh_tls() is not None
    if not (settings.zenoh_user or settings.zenoh_credentials_file or tls):
        return (
            "; no zenoh credentials were given: a rig started by `ralf-hil up` answers only tools with its certificates "
            "(`set -a; . TOOL.env` with the tool.env path its start line prints)"
        )
    if tls:
        return "; the rig may have refused the tool's certificate (a rig from `ralf-hil up` makes new ones each run)"
    return f"; the rig may have refused the credentials of user {settings.zenoh_user or '(from the credentials file)'} (a rig from `ralf-hil up` makes new ones each run)"


def cmd_monitor(args: argparse.Namespace) -> int:
    err = Console(stderr=True)
    try:
        settings = monitor_settings(args.rig_id, args.connect)
    except ConfigError as exc:
        err.print(f"ralf-hil monitor: {exc}", markup=False, highlight=False)
        return 2
    out = Console()
    if args.once:
        try:
            snap = snapshot_once(window_s=args.window, settings=settings)
        except Exception as exc:  # zenoh refuses the configuration, endpoints unreachable...
            err.print(f"ralf-hil monitor: cannot watch rig {settings.rig_id!r}: {zenoh_error_text(exc)}", markup=False, highlight=False)
            return 1
        if args.json:
            sys.stdout.write(json.dumps(snap, indent=2) + "\n")
        else:
            out.print(render(snap))
        if not snap["messages"]:
            err.print(
                f"ralf-hil monitor: nothing heard from rig {settings.rig_id!r} within {args.window:.1f} s{credentials_hint(settings)}",
                markup=False,
                highlight=False,
            )
            return 1
        return 0
    from rich.live import Live

    stop = threading.Event()
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, lambda *_: stop.set())
    try:
        with open_watch(settings) as watch, Live(render(watch.snapshot()), console=out, refresh_per_second=4, screen=False) as live:
            while not stop.wait(1.0 / max(args.refresh, 0.1)):
                live.update(render(watch.snapshot()))
    except KeyboardInterrupt:
        pass
    except Exception as exc:
        err.print(f"ralf-hil monitor: {exc}", markup=False, highlight=False)
        return 1
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0


def register(subparsers: Any) -> None:
    """Add ``monitor`` to ``ralf-hil``."""
    p = subparsers.add_parser(
        "monitor",
        help="live view of a rig's health, liveliness and controller status on zenoh",
        description="Live view of ralf/<rig>/health/*, ralf/<rig>/alive/* and the controller status. "
        "zenoh settings come from RALF_ZENOH_* (mode, connect, listen, multicast scouting) and the options below.",
    )
    p.add_argument("--rig-id", default=None, help="rig to watch (default: RALF_RIG_ID or 'default')")
    p.add_argument(
        "--connect", default=None, metavar="ENDPOINT[,ENDPOINT...]", help="zenoh endpoints to connect to, e.g. tcp/127.0.0.1:7447 (default: RALF_ZENOH_CONNECT)"
    )
    p.add_argument("--once", action="store_true", help="collect for --window seconds, print one snapshot and exit (1 if nothing was heard)")
    p.add_argument(
        "--window", type=_positive, default=2.5, help="collection window of --once in seconds (default 2.5; health comes every RALF_HEALTH_PERIOD_S)"
    )
    p.add_argument("--json", action="store_true", help="with --once: print the snapshot as JSON instead of tables")
    p.add_argument("--refresh", type=_positive, default=4.0, help="live refreshes per second (default 4)")
    p.set_defaults(func=cmd_monitor)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0 or value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value
