"""The rig's access rules hold for any key expression: every role, with its
own valid credentials, puts, deletes, publishes through a declared
publisher, holds a liveliness token and answers queries on the wildcard
(``*``, ``**``, another rig's chunk) and ``$*`` forms of every key of the
rig, and on the exact keys it does not send; none of it reaches a node of
the rig, while the same role's exact keys do. Against sessions configured
as ``ralf-hil up`` configures them (peer mode) and as the compose router
and its clients are (client mode). Loopback only, scouting off, one burst
per role (a few hundred messages)."""

from __future__ import annotations

import time
import zlib
from collections.abc import Iterator
from pathlib import Path

import pytest

from protocol.keys import Keys
from protocol.rig_description import RIG
from service_kit.access import ROLES, sends
from tests.hardening.zenoh_rig import SERVICES, PeerRig, RoutedRig, attacker, wait_peers

pytestmark = pytest.mark.rig


def forms(keys: Keys, key: str) -> list[str]:
    """The key expressions that cover ``key`` without being it."""
    parent, last = key.rsplit("/", 1)
    suffix = key[len(keys.root) + 1 :]
    out = [f"{parent}/*", f"{parent}/**", f"{keys.root}/**", f"ralf/*/{suffix}", "ralf/**", f"{parent}/{last[: max(1, len(last) - 2)]}$*"]
    return list(dict.fromkeys(out))


def protected(keys: Keys) -> dict[str, str]:
    """Every key of the rig -> its channel kind."""
    return {f"{keys.root}/{suffix}": channel.kind for suffix, channel, _ in RIG.expanded()}


Rig = PeerRig | RoutedRig


@pytest.fixture(scope="module", params=["peer", "client"])
def rig(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Rig]:
    mode = request.param
    rig_id = f"acl-wild-{mode}-{zlib.crc32(str(tmp_path_factory.getbasetemp()).encode()) % 100000}"
    started: Rig = (PeerRig if mode == "peer" else RoutedRig).start(rig_id, tmp_path_factory.mktemp(f"acl-{mode}"))
    try:
        yield started
    finally:
        started.close()


def _enforcers(rig: Rig) -> dict[str, object]:
    """Where refusal is decided: every node in peer mode, the router in client mode."""
    return {"router": rig.taps["router"]} if isinstance(rig, RoutedRig) else dict(rig.taps)


@pytest.mark.parametrize("role", ROLES)
def test_no_key_expression_reaches_the_rig_beyond_the_roles_own_keys(rig: Rig, role: str) -> None:
    keys = rig.keys
    mode = "client" if isinstance(rig, RoutedRig) else "peer"
    tag = f"{mode}:{role}".encode()
    own = sends(keys, role)
    taps = rig.taps
    start = {name: len(tap.got) for name, tap in taps.items()}
    session = attacker(role, rig)
    handles: list[object] = []
    try:
        wait_peers(session, len(rig.endpoints))
        attempts = 0
        for key, kind in protected(keys).items():
            for expr in [*forms(keys, key), key]:
                session.put(expr, tag)
                session.delete(expr, attachment=tag)
                publisher = session.declare_publisher(expr)
                publisher.put(tag + b"|pub")
                handles.append(publisher)
                handles.append(session.liveliness().declare_token(expr))
                if kind == "queryable" and (expr != key or key not in own[kind]):
                    # a session that also answers the exact key would answer for these too, rightly
                    handles.append(session.declare_queryable(expr, lambda q: q.reply(q.key_expr, tag)))
                attempts += 4
        marker = tag + b"|marker"
        if own["publication"]:
            session.put(own["publication"][0], marker)
            for name, tap in _enforcers(rig).items():
                assert tap.wait_for(own["publication"][0], marker), f"{role}'s own key never reached {name}"
        else:  # a tool role (reads the whole rig): a query round trip to each enforcer
            for name in _enforcers(rig):
                replies = list(session.get(f"{keys.root}/marker/{name}", timeout=20.0))
                assert any(r.ok is not None for r in replies), f"no marker reply from {name}"
        replies = [r.ok.payload.to_bytes() for r in taps["controller"].session.get(keys.tf, timeout=10.0) if r.ok is not None]
    finally:
        session.close()
    if keys.tf in own["queryable"]:  # the answering role's exact queryable is answered
        answerer = attacker(role, rig)
        try:
            wait_peers(answerer, len(rig.endpoints))
            queryable = answerer.declare_queryable(keys.tf, lambda q: q.reply(q.key_expr, tag + b"|exact"))
            exact: list[bytes] = []
            deadline = time.monotonic() + 20.0  # until the declaration has reached the querier
            while not exact and time.monotonic() < deadline:
                exact = [r.ok.payload.to_bytes() for r in taps["controller"].session.get(keys.tf, timeout=5.0) if r.ok is not None]
            queryable.undeclare()
        finally:
            answerer.close()
        assert exact == [tag + b"|exact"], exact
    assert attempts > 300
    allowed_samples = set(own["publication"])
    allowed_tokens = set(own["liveliness"])
    for name, tap in taps.items():
        new = tap.got[start[name] :]
        samples = {(k, kind) for k, kind, p, a in new if kind.startswith("sample") and (p.startswith(tag) or a == tag)}
        tokens = {k for k, kind, _, _ in new if kind == "token:put"}
        assert {k for k, _ in samples} <= allowed_samples, (name, sorted(samples))
        assert tokens <= allowed_tokens, (name, sorted(tokens))
        if name in _enforcers(rig):
            assert {(k, f"sample:{op}") for k in allowed_samples for op in ("put", "delete")} <= samples, (name, sorted(samples))
            assert allowed_tokens <= tokens, (name, sorted(tokens))
    assert replies == [], replies


@pytest.mark.parametrize("claimed", ["dsp", "launcher"])
def test_a_session_claiming_a_running_nodes_id_links_nowhere(rig: Rig, claimed: str) -> None:
    """A session with the tool's certificate and password claiming the id of
    a running node links nowhere: the claimed node refuses a link to itself,
    every other node already has that id's session, under another user
    name, and refuses to add the link to it."""
    if not isinstance(rig, PeerRig):
        pytest.skip("client mode: the router matches every link by its user name")
    keys = rig.keys
    tag = f"claims {claimed}".encode()
    start = {name: len(tap.got) for name, tap in rig.taps.items()}
    session = attacker("tool", rig, zid=rig.node_ids[claimed])
    try:
        time.sleep(1.0)  # bounded: links are attempted (and refused) meanwhile
        linked = len(list(session.info.peers_zid()))
        for key in (keys.interrupt, keys.flag, keys.health("dsp"), keys.controller_command):
            session.put(key, tag)
        session.put(keys.controller_command, tag + b"|marker")
        # with no link nothing can arrive; with links, the marker follows the forgeries on each
        reached = [name for name, tap in rig.taps.items() if linked and tap.wait_for(keys.controller_command, tag + b"|marker", timeout=5.0)]
    finally:
        session.close()
    assert linked == 0 and reached == [], (linked, reached)
    for name, tap in rig.taps.items():
        assert not [k for k, _, p, _ in tap.got[start[name] :] if p.startswith(tag)], name


def test_a_session_claiming_the_id_of_a_node_that_has_gone_gets_nothing(tmp_path: Path) -> None:
    """After the DSP has gone (its session closed, the others' links to it
    down), a session with the tool's certificate and the DSP's zenoh id links
    to the remaining nodes as the tool: its forged interrupt is refused, its
    own command arrives after it on the same link."""
    rig = PeerRig.start(f"acl-gone-{zlib.crc32(str(tmp_path).encode()) % 100000}", tmp_path)
    keys = rig.keys
    try:
        rig.taps.pop("dsp").close()
        rig.sessions.pop(0).close()  # the DSP's session: the others' links to it close
        session = attacker("tool", rig, [e for n, e in zip(("launcher", *SERVICES), rig.endpoints) if n != "dsp"], zid=rig.node_ids["dsp"])
        try:
            wait_peers(session, 3)
            session.put(keys.interrupt, b"forged")
            session.put(keys.controller_command, b"marker")  # the tool role's own key: arrives after
            assert rig.taps["controller"].wait_for(keys.controller_command, b"marker")
        finally:
            session.close()
        assert not rig.taps["controller"].wait_for(keys.interrupt, b"forged", timeout=0.0)
    finally:
        rig.close()
