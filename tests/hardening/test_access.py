"""zenoh's own authentication and access control, as the rig configures it
(service_kit.access), checked against a real zenoh 1.10 node on loopback: a
session without valid credentials (user and password, as the compose router
takes them; certificates: tests/hardening/test_certificates.py) cannot connect; the rules deny by
default and no allow rule is wider than one key (what each role's sessions
can and cannot do with them: tests/hardening/test_access_wildcards.py)."""

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
    router_config,
    sends,
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


def test_rules_deny_by_default_and_allow_no_wider_than_a_key() -> None:
    config = acl_config(KEYS, scenarios=True)
    assert config["default_permission"] == "deny"
    assert all(rule["permission"] == "allow" for rule in config["rules"])
    wide = {k for rule in config["rules"] for k in rule["key_exprs"] if "*" in k or "$" in k}
    assert wide == {"**", f"{KEYS.root}/**"}
    for rule in config["rules"]:
        if "**" in rule["key_exprs"]:  # a node's own declarations, to everyone
            assert rule["flows"] == ["egress"] and not {"put", "delete", "reply", "liveliness_token"} & set(rule["messages"]), rule
        if f"{KEYS.root}/**" in rule["key_exprs"]:  # observers read the whole rig
            assert not {"put", "delete", "declare_queryable", "liveliness_token"} & set(rule["messages"]) or rule["flows"] == ["egress"], rule


def test_each_key_is_sent_by_its_declared_senders_only() -> None:
    for key, roles in publishers(KEYS, scenarios=True).items():
        for role in ROLES:
            assert (key in sends(KEYS, role, scenarios=True)["publication"]) == (role in roles), (key, role)
    assert publishers(KEYS, scenarios=True)[KEYS.scenario] == ("tester",) and publishers(KEYS)[KEYS.scenario] == ()
    assert sends(KEYS, "dsp")["queryable"] == [KEYS.tf] and sends(KEYS, "dsp")["liveliness"] == [KEYS.alive("dsp")]
    assert sends(KEYS, "launcher") == {"publication": [], "queryable": [], "liveliness": []}


@pytest.mark.parametrize(("by", "field"), [("certificate", "cert_common_names"), ("user", "usernames")])
def test_each_role_is_known_by_one_proof_only_never_by_an_id(by: str, field: str) -> None:
    """Peer mode names roles by certificate only, the compose router by user name only:
    a session's password cannot lend it another role than its certificate's."""
    config = acl_config(KEYS, scenarios=True, by=by)  # type: ignore[arg-type]
    subjects = {s["id"]: s for s in config["subjects"]}
    assert subjects == {f"{by} {role}": {"id": f"{by} {role}", field: [role]} for role in ROLES}
    for policy in config["policies"]:
        if policy["id"] in ROLES:
            assert policy["subjects"] == [f"{by} {policy['id']}"]
    assert router_config(KEYS, "/c")["access_control"]["subjects"][0] == {"id": f"user {ROLES[0]}", "usernames": [ROLES[0]]}


def test_more_rigs_get_their_own_rules() -> None:
    config = acl_config(KEYS, more_rigs=[Keys("other")])
    keys = {k for rule in config["rules"] for k in rule["key_exprs"]}
    assert Keys("other").interrupt in keys and KEYS.interrupt in keys
