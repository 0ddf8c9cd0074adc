"""zenoh's own authentication and access control, as the rig configures it
(service_kit.access), checked against a real zenoh 1.10 node on loopback: a
session without valid credentials cannot connect, and each role's puts on
each protected key arrive only where the rules allow them."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from protocol.keys import Keys
from service_kit.access import (
    ROLES,
    acl_config,
    generate_credentials,
    insert_access,
    publishers,
    write_credentials_file,
)
from workbench.launcher import free_tcp_port

RIG = "acl-test"
KEYS = Keys(RIG)


def _config(listen: str | None = None, connect: str | None = None) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    if listen:
        config.insert_json5("listen/endpoints", json.dumps([listen]))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps([connect]))
    return config


class Receiver:
    def __init__(self, session: zenoh.Session) -> None:
        self.got: list[tuple[str, bytes]] = []
        self.cond = threading.Condition()
        self.sub = session.declare_subscriber("ralf/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        with self.cond:
            self.got.append((str(sample.key_expr), sample.payload.to_bytes()))
            self.cond.notify_all()

    def wait_for(self, key: str, payload: bytes, timeout: float = 10.0) -> bool:
        with self.cond:
            return self.cond.wait_for(lambda: (key, payload) in self.got, timeout)


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, dict[str, str], Receiver, Path]]:
    creds = generate_credentials()
    path = write_credentials_file(tmp_path_factory.mktemp("acl") / "credentials.txt", creds)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    node = zenoh.open(insert_access(_config(listen=endpoint), RIG, "dsp", creds["dsp"], str(path), acl=True))
    receiver = Receiver(node)
    try:
        yield endpoint, creds, receiver, path
    finally:
        receiver.sub.undeclare()
        node.close()


def _open_as(endpoint: str, user: str, password: str) -> zenoh.Session:
    return zenoh.open(insert_access(_config(connect=endpoint), RIG, user, password))


def test_credentials_file_is_owner_only(rig: tuple[str, dict[str, str], Receiver, Path]) -> None:
    assert rig[3].stat().st_mode & 0o077 == 0


@pytest.mark.parametrize(("user", "password"), [(None, None), ("controller", "wrong"), ("intruder", "x")])
def test_without_valid_credentials_nothing_connects(rig: tuple[str, dict[str, str], Receiver, Path], user: str | None, password: str | None) -> None:
    endpoint, _, receiver, _ = rig
    session = zenoh.open(_config(connect=endpoint)) if user is None else _open_as(endpoint, user, password or "")
    try:
        time.sleep(0.5)  # let a connection be attempted
        assert list(session.info.peers_zid()) == []
        session.put(KEYS.interrupt, b"forged")
        session.put("ralf/x/unprotected", b"forged")
    finally:
        session.close()
    assert all(payload != b"forged" for _, payload in receiver.got)


PROTECTED = [KEYS.batch, KEYS.dsp_config, KEYS.interrupt, KEYS.flag, KEYS.truth, KEYS.health("dsp"), KEYS.controller_command, KEYS.scenario]


@pytest.mark.parametrize("role", [r for r in ROLES if r != "dsp"])
def test_each_role_publishes_only_its_own_keys(rig: tuple[str, dict[str, str], Receiver, Path], role: str) -> None:
    endpoint, creds, receiver, _ = rig
    allowed = publishers(KEYS)
    session = _open_as(endpoint, role, creds[role])
    try:
        deadline = time.monotonic() + 10
        while not list(session.info.peers_zid()) and time.monotonic() < deadline:
            time.sleep(0.05)
        for key in PROTECTED:
            session.put(key, f"{role}:{key}".encode())
        marker = f"ralf/{RIG}/marker/{role}"
        session.put(marker, b"end")  # same link, same priority: arrives after the others
        assert receiver.wait_for(marker, b"end")
    finally:
        session.close()
    for key in PROTECTED:
        arrived = (key, f"{role}:{key}".encode()) in receiver.got
        assert arrived == (role in allowed[key]), (role, key)


def test_rules_cover_every_key_and_role() -> None:
    config = acl_config(KEYS, scenarios=True)
    protected = {k for rule in config["rules"] for k in rule["key_exprs"]}
    assert set(publishers(KEYS)) <= protected | {k for k, roles in publishers(KEYS).items() if set(roles) == set(ROLES)}
    assert publishers(KEYS, scenarios=True)[KEYS.scenario] == ("tester",) and publishers(KEYS)[KEYS.scenario] == ()
    assert {s["id"] for s in config["subjects"]} == {f"role {r}" for r in ROLES}
