"""Who may drive the rig: who a session is (mutual TLS on every link, with
zenoh's ``transport/auth/usrpwd`` beside it) and what its role may do
(zenoh's ``access_control``), generated from the rig's description
(:mod:`protocol.rig_description`).

Every session of a rig has a role (:data:`ROLES`): a certificate whose
common name is the role (``ralf-hil up`` and ``ralf-hil credentials`` for
docker compose, :mod:`workbench.certificates`), and a user name naming it
with a password.

The access rules deny by default and allow each role exactly what the rig
description says it does, on the exact keys (:func:`acl_config`):

* sending (:data:`SEND_MESSAGES`): only the controller publishes batches,
  its status and the DSP's configuration; only the DSP publishes flags,
  interrupts and configuration acknowledgements and answers TF queries;
  only the plant publishes ground truth and plant events; each service only
  its own health and liveliness token; tools (``ralf-hil reconfigure``) only
  commands; scenario commands only the ``tester`` role, and only where
  ``zenoh_acl`` is ``scenarios``;
* reading (:data:`READ_MESSAGES`): each board subscribes to and queries
  its declared inputs; the observer roles (:data:`OBSERVERS`) read the
  whole rig.

zenoh allows a message only if an allow rule's key expression *includes*
the message's own key expression, so a put, delete, reply or token on a
wildcard (``ralf/<rig>/dsp/*``, ``ralf/<rig>/**``, ``ralf/*/dsp/interrupt``,
``ralf/<rig>/dsp/interr$*``) is refused even for the key's own sender:
no allow rule is wider than one key.

Every node applies the rules to every link, ingress and egress (zenoh 1.x
peers do not relay, so the subject of a message is its originator; in
client mode the router applies them and the clients, whose one link is the
one they opened to it, do not). A link's subject is its role, proven one
way per mode. In peer mode (``ralf-hil up``) every link is mutual TLS: both
ends show a certificate of the run's own authority whose common name is
the role (:mod:`workbench.certificates`), so each end knows the other's
role, the end that opened the link as well as the one that accepted it,
and the rules name roles by certificate only. Every session there also
authenticates with its role's user name and password: zenoh adds a second
link from an already linked zenoh id to that id's session when the user
names agree, and the certificate does not enter that comparison, so
without passwords a session could join a running node's session by
claiming its id. In client mode (docker compose) a client's one link is
the one it opened to its router, mutual TLS as well: the router accepts
only a certificate of the authority ``ralf-hil credentials`` made (and the
role's password) and is the one end that applies the rules, by
certificate; the client accepts only the router's certificate of the same
authority (:func:`router_config`). Schema: zenoh 1.10's
``AclConfig`` (``enabled``, ``default_permission``, ``rules`` of
``id``/``permission``/``flows``/``messages``/``key_exprs``, ``subjects`` of
``id``/``usernames``/``cert_common_names``, ``policies`` of ``id``/``rules``/``subjects``),
checked against running sessions in ``tests/hardening/test_access.py`` and
``tests/hardening/test_access_wildcards.py``.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Final, Literal

from protocol.keys import Keys
from protocol.rig_description import RIG, Channel

ROLES: tuple[str, ...] = RIG.roles
"""Session roles: the three boards, ``ralf-hil up``'s observer, tools, and test harnesses."""
SERVICES: tuple[str, ...] = RIG.service_names


def _senders(channel: Channel, senders: tuple[str, ...], scenarios: bool) -> tuple[str, ...]:
    if channel.gated_by == "zenoh_acl=scenarios" and not scenarios:
        return ()
    return senders


def publishers(keys: Keys, scenarios: bool = False) -> dict[str, tuple[str, ...]]:
    """Key expression -> the roles allowed to publish (put/delete) on it: the
    declared senders of every publication channel of :data:`protocol.rig_description.RIG`."""
    return {f"{keys.root}/{suffix}": _senders(channel, senders, scenarios) for suffix, channel, senders in RIG.expanded() if channel.kind == "publication"}


SEND_MESSAGES: Final[dict[str, tuple[str, ...]]] = {
    "publication": ("put", "delete"),
    "queryable": ("declare_queryable", "reply"),
    "liveliness": ("liveliness_token",),
}
"""What a channel's senders do on it, per channel kind (zenoh 1.x ACL message names)."""

READ_MESSAGES: Final[dict[str, tuple[str, ...]]] = {
    "publication": ("declare_subscriber",),
    "queryable": ("query",),
    "liveliness": ("declare_liveliness_subscriber", "liveliness_query"),
}
"""What a channel's readers do on it, per channel kind."""

DELIVERED_MESSAGES: Final[dict[str, tuple[str, ...]]] = {
    "publication": ("put", "delete"),
    "queryable": ("reply",),
    "liveliness": ("liveliness_token",),
}
"""What a node hands on (egress) to a reader of a channel, per channel kind."""

DECLARATIONS: Final[tuple[str, ...]] = ("declare_subscriber", "declare_queryable", "query", "declare_liveliness_subscriber", "liveliness_query")
"""A node's own interest, declared to every session it talks to (egress, any key)."""

OBSERVERS: Final[tuple[str, ...]] = RIG.tools
"""Roles that may read the whole rig (``ralf/<rig>/**``): the launcher's
observer (``up``'s summary, ``--record``'s tap), tools (``monitor``,
``record``, ``reconfigure``'s acknowledgement) and test harnesses."""


def sends(keys: Keys, role: str, scenarios: bool = False) -> dict[str, list[str]]:
    """Channel kind -> the exact keys ``role`` sends on (publishes, answers,
    holds a token on), as the rig description declares."""
    out: dict[str, list[str]] = {kind: [] for kind in SEND_MESSAGES}
    for suffix, channel, senders in RIG.expanded():
        if role in _senders(channel, senders, scenarios):
            out[channel.kind].append(f"{keys.root}/{suffix}")
    return out


def reads(keys: Keys, role: str) -> dict[str, list[str]]:
    """Channel kind -> the key expressions ``role`` may read (subscribe,
    query, watch tokens): a board its declared inputs, an observer the whole rig."""
    if role in OBSERVERS:
        return {kind: [f"{keys.root}/**"] for kind in READ_MESSAGES}
    out: dict[str, list[str]] = {kind: [] for kind in READ_MESSAGES}
    for suffix, channel, _ in RIG.expanded():
        if role in channel.readers:
            out[channel.kind].append(f"{keys.root}/{suffix}")
    return out


def _allow(rule_id: str, flow: str, messages: Iterable[str], key_exprs: Iterable[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": [flow], "messages": list(messages), "key_exprs": list(key_exprs)}


def _role_rules(keys: Keys, role: str, scenarios: bool, prefix: str) -> list[dict[str, Any]]:
    rules: list[dict[str, Any]] = []
    sent, read = sends(keys, role, scenarios), reads(keys, role)
    for kind in SEND_MESSAGES:
        if sent[kind]:
            rules.append(_allow(f"{prefix}{role} sends {kind}", "ingress", SEND_MESSAGES[kind], sent[kind]))
        if read[kind]:
            rules.append(_allow(f"{prefix}{role} reads {kind}", "ingress", READ_MESSAGES[kind], read[kind]))
            rules.append(_allow(f"{prefix}{role} receives {kind}", "egress", DELIVERED_MESSAGES[kind], read[kind]))
    return rules


SUBJECT_FIELDS: Final[dict[str, str]] = {"certificate": "cert_common_names", "user": "usernames"}
"""How a link proves its role: its certificate's common name (mutual TLS: every
link of a local rig and of the compose rig) or the user name it authenticated
with (a router configured without TLS)."""


def acl_config(keys: Keys, scenarios: bool = False, more_rigs: Iterable[Keys] = (), by: Literal["certificate", "user"] = "certificate") -> dict[str, Any]:
    """The ``access_control`` section of every node of the rig: deny by
    default; each role (a link's certificate name, or with ``by="user"``
    the user name its client authenticated with: one of them, never
    either) may send what the rig description says it sends and read what
    it reads, on those exact keys only, so no key expression (``*``,
    ``**``, ``$*``, another rig's chunk) covers more: zenoh allows a
    message only if an allow rule's key expression includes the message's
    whole key expression.

    A node hands out (egress) to each role only what that role reads, and
    declares its own interest (subscribers, queryables, queries) to all.
    ``more_rigs``: further rigs the same session serves (one DSP process
    for several rigs)."""
    rules: list[dict[str, Any]] = [_allow("own declarations", "egress", DECLARATIONS, ["**"])]
    subjects: list[dict[str, Any]] = [{"id": f"{by} {role}", SUBJECT_FIELDS[by]: [role]} for role in ROLES]
    policies: list[dict[str, Any]] = [{"id": "declarations", "rules": ["own declarations"], "subjects": [s["id"] for s in subjects]}]
    rigs = [keys, *(k for k in more_rigs if k != keys)]
    for role in ROLES:
        role_rules = [rule for rig in rigs for rule in _role_rules(rig, role, scenarios, f"{rig.rig_id}: ")]
        rules += role_rules
        if role_rules:
            policies.append({"id": role, "rules": [r["id"] for r in role_rules], "subjects": [f"{by} {role}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}


def generate_credentials(roles: Iterable[str] = ROLES) -> dict[str, str]:
    """A fresh random password per role (for one run)."""
    return {role: secrets.token_urlsafe(24) for role in roles}


def write_credentials_file(path: str | Path, credentials: Mapping[str, str]) -> Path:
    """The ``user:password`` dictionary zenoh reads, readable by the owner only."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(p, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.writelines(f"{user}:{password}\n" for user, password in credentials.items())
    return p


def router_config(
    keys: Keys,
    credentials_file: str,
    listen: str = "tcp/0.0.0.0:7447",
    scenarios: bool = False,
    tls: tuple[str, str, str] | None = None,
) -> dict[str, Any]:
    """A zenoh router's configuration for the distributed rig (docker compose):
    authentication of every client, the rig's access rules, and (used by
    ``zenohd``, which has the plugins) the REST plugin on port 8000 with an
    in-memory storage of each rig's latest health and controller status, so
    ``curl http://localhost:8000/ralf/<rig>/health/**`` answers: a GET is a
    zenoh query, and health is published, not queryable, so the storage
    keeps the latest sample of every such key and answers for it.

    With ``tls`` (the router's authority, certificate and key files) every
    link is mutual TLS, as in a local rig: the router shows its certificate
    and accepts only clients holding one of the run's authority, ``listen``
    becomes ``tls/``, and the rules name roles by certificate. The clients'
    passwords still bind a zenoh id to its role (see the module's text)."""
    section: dict[str, Any] = {"auth": {"usrpwd": {"dictionary_file": credentials_file}}}
    if tls is not None:
        section["link"] = {"tls": tls_section(*tls)}
        listen = "tls/" + listen.removeprefix("tcp/") if listen.startswith("tcp/") else listen
    return {
        "mode": "router",
        "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": section,
        "access_control": acl_config(keys, scenarios, by="certificate" if tls is not None else "user"),
        "plugins": ROUTER_PLUGINS,
    }


ROUTER_PLUGINS: dict[str, Any] = {
    "rest": {"http_port": 8000},
    "storage_manager": {
        "storages": {
            "ralf_health": {"key_expr": "ralf/*/health/*", "volume": "memory"},
            "ralf_status": {"key_expr": "ralf/*/controller/status", "volume": "memory"},
        },
    },
}
"""The compose router's plugins: REST on 8000 and the health/status storage."""


def tls_section(ca: str, certificate: str, key: str, inline: bool = False) -> dict[str, Any]:
    """``transport/link/tls`` for mutual TLS: this session's certificate on
    the links it accepts and on those it opens, and only peers whose
    certificate the run's authority signed. ``inline``: the three values
    are base64 of the PEM files (zenoh's ``*_base64`` options), not paths."""
    suffix = "_base64" if inline else ""
    return {
        f"root_ca_certificate{suffix}": ca,
        "enable_mtls": True,
        f"listen_certificate{suffix}": certificate,
        f"listen_private_key{suffix}": key,
        f"connect_certificate{suffix}": certificate,
        f"connect_private_key{suffix}": key,
    }


def insert_access(
    config: Any,
    rig_id: str,
    user: str = "",
    password: str = "",
    credentials_file: str = "",
    acl: bool = False,
    scenarios: bool = False,
    more_rigs: Iterable[str] = (),
    tls: tuple[str, str, str] | None = None,
    tls_inline: bool = False,
) -> Any:
    """Add authentication and the rig's access rules to a ``zenoh.Config``
    (``more_rigs``: the rules of further rigs the same session serves, e.g.
    one DSP process for several rigs; ``tls``: the files of mutual TLS,
    authority, certificate and key, or with ``tls_inline`` base64 of each)."""
    if user or credentials_file:
        usrpwd: dict[str, str] = {}
        if user:
            usrpwd.update(user=user, password=password)
        if credentials_file:
            usrpwd["dictionary_file"] = credentials_file
        config.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    if tls is not None:
        config.insert_json5("transport/link/tls", json.dumps(tls_section(*tls, inline=tls_inline)))
    if acl:
        section = acl_config(Keys(rig_id), scenarios, [Keys(r) for r in more_rigs], by="certificate" if tls is not None else "user")
        config.insert_json5("access_control", json.dumps(section))
    return config


def _on(value: str) -> bool:
    return value.lower() in ("1", "true", "yes", "on")


def insert_access_from_env(config: Any, rig_id: str, env: Mapping[str, str]) -> Any:
    """:func:`insert_access` from ``RALF_ZENOH_*`` variables (e.g. a
    launcher's own session, configured like the services)."""
    tls = tuple(env.get(f"RALF_ZENOH_TLS_{part}", "") for part in ("CA", "CERTIFICATE", "KEY"))
    inline = tuple(env.get(f"RALF_ZENOH_TLS_{part}_BASE64", "") for part in ("CA", "CERTIFICATE", "KEY"))
    if all(inline):
        tls = inline
    return insert_access(
        config,
        rig_id,
        user=env.get("RALF_ZENOH_USER", ""),
        password=env.get("RALF_ZENOH_PASSWORD", ""),
        credentials_file=env.get("RALF_ZENOH_CREDENTIALS_FILE", ""),
        acl=_on(env.get("RALF_ZENOH_ACL", "")) or env.get("RALF_ZENOH_ACL", "").lower() == "scenarios",
        scenarios=env.get("RALF_ZENOH_ACL", "").lower() == "scenarios",
        tls=(tls[0], tls[1], tls[2]) if all(tls) else None,
        tls_inline=all(inline),
    )


def role_env(role: str, credentials: Mapping[str, str]) -> dict[str, str]:
    """The variables that make a session authenticate as ``role``."""
    return {"RALF_ZENOH_USER": role, "RALF_ZENOH_PASSWORD": credentials[role]}
