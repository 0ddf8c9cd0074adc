"""Sessions configured exactly as the rig configures them (peer mode: the
launcher's plan and the run's certificates, each service's settings through
``service_kit.transport.zenoh_config``; client mode: the compose router's
mutual TLS and access rules), each with a tap on the whole rig, and attacker
sessions that authenticate with a role's credentials (its certificate and
its password, in either mode). Loopback only, scouting off."""

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
from service_kit.access import ROLES, generate_credentials, insert_access, router_config, write_credentials_file
from service_kit.transport import zenoh_config
from workbench.certificates import LOOPBACK_NAMES, RoleCertificate, write_role_certificates
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


def attacker(role: str, rig: PeerRig | RoutedRig, endpoints: list[str] | None = None, zid: str = "") -> zenoh.Session:
    """A stock zenoh session, no access rules of its own, holding ``role``'s
    credentials of ``rig`` (``zid``: claiming that zenoh id), connected to
    every node of the rig (or to ``endpoints``)."""
    config = base_config("peer" if isinstance(rig, PeerRig) else "client", connect=endpoints or rig.endpoints)
    if zid:
        config.insert_json5("id", json.dumps(zid))
    files = rig.certificates[role]
    tls = (str(files.ca), str(files.certificate), str(files.key))
    return zenoh.open(insert_access(config, rig.keys.rig_id, user=role, password=rig.credentials[role], tls=tls))


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
    rig, as ``ralf-hil up`` configures them (certificates, passwords, rules)."""

    keys: Keys
    certificates: dict[str, RoleCertificate]
    credentials: dict[str, str]
    endpoints: list[str]
    taps: dict[str, Tap]
    sessions: list[Any]
    observer: RigObserver
    node_ids: dict[str, str]
    """Role -> the zenoh id its session happened to get."""
    plan: Any = None
    """The launcher's plan (each service's variables)."""

    @classmethod
    def start(cls, rig_id: str, directory: Path, acl: str = "on", leave_out: tuple[str, ...] = ()) -> PeerRig:
        """``acl``: ``on`` (the tester's certificate exists, its keys stay refused) or ``scenarios``;
        ``leave_out``: services the caller starts itself (as processes, from :attr:`plan`)."""
        from workbench.cli import provision_access

        plan = RigPlan.local(rig_id=rig_id)
        provision_access(plan, directory, scenarios=True)  # the tester's certificate too
        plan.common_env["RALF_ZENOH_ACL"] = acl
        certificates = {
            role: RoleCertificate(directory / "ca.pem", directory / f"{role}.pem", directory / f"{role}.key")
            for role in ROLES
            if (directory / f"{role}.pem").exists()
        }
        credentials = dict(line.split(":", 1) for line in (directory / "zenoh-credentials.txt").read_text().splitlines())
        tool_env = dict(line.split("=", 1) for line in (directory / "tool.env").read_text().splitlines())
        tls = {"RALF_ZENOH_TLS_CA", "RALF_ZENOH_TLS_CERTIFICATE", "RALF_ZENOH_TLS_KEY"}
        assert set(tool_env) == {*tls, "RALF_ZENOH_USER", "RALF_ZENOH_PASSWORD", "RALF_ZENOH_CONNECT", "RALF_CAN_PORT", "RALF_RIG_ID"}, tool_env
        keys = Keys(rig_id)
        observer = RigObserver(plan)
        taps = {"launcher": Tap(observer.session, keys.root, "launcher")}
        sessions = []
        node_ids = {"launcher": str(observer.session.info.zid())}
        for name in (n for n in SERVICES if n not in leave_out):
            settings = settings_from_env({**plan.common_env, **plan.service_env[name]})
            session = zenoh.open(zenoh_config(settings))
            sessions.append(session)
            node_ids[name] = str(session.info.zid())
            taps[name] = Tap(session, keys.root, name)
        endpoints = [plan.zenoh_endpoint] + [f"tls/127.0.0.1:{plan.service_ports[n]}" for n in SERVICES if n not in leave_out]
        for session in sessions:
            wait_peers(session, len(SERVICES) - len(leave_out))
        return cls(keys, certificates, credentials, endpoints, taps, sessions, observer, node_ids, plan)

    def close(self) -> None:
        for tap in self.taps.values():
            tap.close()
        for session in self.sessions:
            session.close()
        self.observer.close()


@dataclass
class RoutedRig:
    """The distributed rig: a router as ``ralf-hil credentials`` configures it
    for compose (mutual TLS with the router's certificate, passwords, the
    rules by certificate; its plugins left out: the Python session has none),
    and the services and an observer as its clients, each with its role's
    certificate of the same authority."""

    keys: Keys
    certificates: dict[str, RoleCertificate]
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
        certificates = write_role_certificates(directory, ["router", *ROLES], hosts=(), hosts_of={"router": LOOPBACK_NAMES})
        endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
        router_files = certificates["router"]
        section = router_config(keys, str(path), listen=endpoint, tls=(str(router_files.ca), str(router_files.certificate), str(router_files.key)))
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
                zenoh_tls_ca=str(certificates[name].ca),
                zenoh_tls_certificate=str(certificates[name].certificate),
                zenoh_tls_key=str(certificates[name].key),
            )
            session = zenoh.open(zenoh_config(settings))
            wait_peers(session, 1)
            sessions.append(session)
            taps[name] = Tap(session, keys.root, name)
        return cls(keys, certificates, credentials, [endpoint], router, taps, sessions)

    def close(self) -> None:
        for tap in self.taps.values():
            tap.close()
        for session in self.sessions:
            session.close()
        self.router.close()
