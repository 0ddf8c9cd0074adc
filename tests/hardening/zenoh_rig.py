"""Sessions configured exactly as the rig configures them (peer mode: the
launcher's plan and credentials, each service's settings through
``service_kit.transport.zenoh_config``; client mode: the compose router's
access rules), each with a tap on the whole rig, and attacker sessions that
authenticate with a role's credentials. Loopback only, scouting off."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from protocol.keys import Keys
from protocol.rig_description import RIG
from protocol.settings import CommonSettings
from service_kit.access import generate_credentials, router_config, write_credentials_file
from service_kit.transport import zenoh_config
from workbench.launcher import RigObserver, RigPlan, free_tcp_port

SERVICES = RIG.service_names


def settings_from_env(env: dict[str, str]) -> CommonSettings:
    """A service's settings from the ``RALF_*`` variables the launcher gives it."""
    values = {k[len("RALF_") :].lower(): v for k, v in env.items() if k.startswith("RALF_")}
    return CommonSettings(**values)


@dataclass
class Tap:
    """Everything a session receives under the rig's root: samples (key,
    kind, payload, attachment) and liveliness changes."""

    session: Any
    root: str
    name: str
    got: list[tuple[str, str, bytes, bytes]] = field(default_factory=list)
    cond: threading.Condition = field(default_factory=threading.Condition)

    def __post_init__(self) -> None:
        self._handles = [
            self.session.declare_subscriber(f"{self.root}/**", lambda s: self._on(s, "sample")),
            self.session.liveliness().declare_subscriber(f"{self.root}/**", lambda s: self._on(s, "token")),
            self.session.declare_queryable(f"{self.root}/marker/{self.name}", self._on_query),
        ]

    def _on(self, sample: zenoh.Sample, what: str) -> None:
        kind = f"{what}:{'put' if sample.kind == zenoh.SampleKind.PUT else 'delete'}"
        payload = sample.payload.to_bytes()
        attachment = sample.attachment.to_bytes() if sample.attachment is not None else b""
        with self.cond:
            self.got.append((str(sample.key_expr), kind, payload, attachment))
            self.cond.notify_all()

    def _on_query(self, query: zenoh.Query) -> None:
        query.reply(query.key_expr, b"marker")

    def wait_for(self, key: str, payload: bytes, timeout: float = 20.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: any(k == key and p == payload for k, _, p, _ in self.got), timeout)

    def tagged(self, tag: bytes) -> list[tuple[str, str]]:
        """(key, kind) of every sample carrying ``tag`` in its payload or attachment."""
        with self.cond:
            return [(k, kind) for k, kind, p, a in self.got if tag in (p, a)]

    def tokens(self) -> set[str]:
        with self.cond:
            return {k for k, kind, _, _ in self.got if kind.startswith("token")}

    def close(self) -> None:
        for h in self._handles:
            h.undeclare()


def base_config(mode: str = "peer", connect: Iterable[str] = (), listen: Iterable[str] = ()) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return config


def attacker(role: str, password: str, endpoints: list[str], mode: str = "peer", zid: str = "") -> zenoh.Session:
    """A stock zenoh session, no access rules of its own, authenticated as
    ``role`` (``zid``: claiming that zenoh id)."""
    config = base_config(mode, connect=endpoints)
    if zid:
        config.insert_json5("id", json.dumps(zid))
    config.insert_json5("transport/auth/usrpwd", json.dumps({"user": role, "password": password}))
    return zenoh.open(config)


def wait_peers(session: zenoh.Session, count: int, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        n = len(list(session.info.peers_zid())) + len(list(session.info.routers_zid()))
        if n >= count:
            return
        time.sleep(0.05)
    raise AssertionError(f"session did not reach {count} nodes within {timeout:.0f} s")


@dataclass
class PeerRig:
    """The three services' sessions and the launcher's observer of a local
    rig, as ``ralf-hil up`` configures them (credentials, rules, node ids)."""

    keys: Keys
    credentials: dict[str, str]
    endpoints: list[str]
    taps: dict[str, Tap]
    sessions: list[Any]
    observer: RigObserver
    node_ids: dict[str, str]

    @classmethod
    def start(cls, rig_id: str, directory: Path) -> PeerRig:
        from workbench.cli import provision_access

        plan = RigPlan.local(rig_id=rig_id)
        provision_access(plan, directory)
        credentials = {}
        for line in Path(plan.common_env["RALF_ZENOH_CREDENTIALS_FILE"]).read_text().splitlines():
            user, _, password = line.partition(":")
            credentials[user] = password
        for line in (directory / "tool.env").read_text().splitlines():
            assert line.startswith(("RALF_ZENOH_USER=", "RALF_ZENOH_PASSWORD=", "RALF_RIG_ID="))
        keys = Keys(rig_id)
        observer = RigObserver(plan)
        taps = {"launcher": Tap(observer.session, keys.root, "launcher")}
        sessions = []
        for name in SERVICES:
            settings = settings_from_env({**plan.common_env, **plan.service_env[name]})
            session = zenoh.open(zenoh_config(settings))
            sessions.append(session)
            taps[name] = Tap(session, keys.root, name)
        endpoints = [f"tcp/127.0.0.1:{plan.zenoh_port}"] + [f"tcp/127.0.0.1:{plan.service_ports[n]}" for n in SERVICES]
        for session in sessions:
            wait_peers(session, len(SERVICES))
        node_ids = dict(entry.split(":") for entry in plan.common_env["RALF_ZENOH_NODE_IDS"].split(","))
        return cls(keys, credentials, endpoints, taps, sessions, observer, node_ids)

    def close(self) -> None:
        for tap in self.taps.values():
            tap.close()
        for session in self.sessions:
            session.close()
        self.observer.close()


@dataclass
class RoutedRig:
    """The distributed rig: a router with the rules ``ralf-hil credentials``
    writes for compose (its plugins left out: the Python session has none),
    and the services and an observer as its clients."""

    keys: Keys
    credentials: dict[str, str]
    endpoints: list[str]
    router: Any
    taps: dict[str, Tap]
    sessions: list[Any]

    @classmethod
    def start(cls, rig_id: str, directory: Path) -> RoutedRig:
        keys = Keys(rig_id)
        credentials = generate_credentials()
        path = write_credentials_file(directory / "zenoh-credentials.txt", credentials)
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        section = router_config(keys, str(path), listen=endpoint)
        del section["plugins"]
        section["scouting"]["gossip"] = {"enabled": False}
        router = zenoh.open(zenoh.Config.from_json5(json.dumps(section)))
        taps = {"router": Tap(router, keys.root, "router")}
        sessions = []
        for name in (*SERVICES, "launcher"):
            settings = CommonSettings(
                rig_id=rig_id,
                zenoh_mode="client",
                zenoh_connect=endpoint,
                zenoh_user=name,
                zenoh_password=credentials[name],
                zenoh_acl=True,
            )
            session = zenoh.open(zenoh_config(settings))
            wait_peers(session, 1)
            sessions.append(session)
            taps[name] = Tap(session, keys.root, name)
        return cls(keys, credentials, [endpoint], router, taps, sessions)

    def close(self) -> None:
        for tap in self.taps.values():
            tap.close()
        for session in self.sessions:
            session.close()
        self.router.close()
