"""Who may drive the rig: zenoh's own authentication (``transport/auth/usrpwd``)
and access control (``access_control``), generated from the rig's description (:mod:`protocol.rig_description`).

Every session of a rig authenticates with a user name naming its role
(:data:`ROLES`) and a password; a node that has the credentials file
(``user:password`` lines) accepts only sessions that present one of them.
The access rules then let each role publish only what its board publishes
(:func:`publishers`): only the controller publishes batches, its status and
the DSP's configuration; only the DSP publishes flags, interrupts,
configuration acknowledgements and answers TF queries; only the plant
publishes ground truth and plant events; each service only its own health
and liveliness; tools (``ralf-hil reconfigure``) only commands; scenario
commands only the ``tester`` role, and only where ``zenoh_acl_scenarios`` is
on. Everything else (subscribing, querying) is allowed.

The rules are applied by every receiving node on ``ingress`` (zenoh 1.x
peers do not relay, so the subject of a message is its originator; in
client mode the router applies them). Schema: zenoh 1.10's ``AclConfig``
(``enabled``, ``default_permission``, ``rules`` of ``id``/``permission``/
``flows``/``messages``/``key_exprs``, ``subjects`` of ``id``/``usernames``,
``policies`` of ``rules``/``subjects``), checked by experiment in
``tests/hardening/test_access.py``.
"""

from __future__ import annotations

import json
import os
import secrets
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from protocol.keys import Keys
from protocol.rig_description import RIG, Channel

ROLES: tuple[str, ...] = RIG.roles
"""Session roles: the three boards, ``ralf-hil up``'s observer, tools, and test harnesses."""
SERVICES: tuple[str, ...] = RIG.service_names


def _senders(channel: Channel, senders: tuple[str, ...], scenarios: bool) -> tuple[str, ...]:
    if channel.gated_by == "zenoh_acl_scenarios" and not scenarios:
        return ()
    return senders


def publishers(keys: Keys, scenarios: bool = False) -> dict[str, tuple[str, ...]]:
    """Key expression -> the roles allowed to publish (put/delete) on it: the
    declared senders of every publication channel of :data:`protocol.rig_description.RIG`."""
    return {f"{keys.root}/{suffix}": _senders(channel, senders, scenarios) for suffix, channel, senders in RIG.expanded() if channel.kind == "publication"}


def _rule(rule_id: str, messages: Iterable[str], key_exprs: Iterable[str]) -> dict[str, Any]:
    return {"id": rule_id, "permission": "deny", "flows": ["ingress"], "messages": list(messages), "key_exprs": list(key_exprs)}


_DENIED_MESSAGES: dict[str, tuple[str, ...]] = {
    "publication": ("put", "delete"),
    "queryable": ("declare_queryable", "reply"),
    "liveliness": ("liveliness_token",),
}
"""What a role that is not a channel's sender may not do on it, per channel kind."""


def acl_config(keys: Keys, scenarios: bool = False) -> dict[str, Any]:
    """The ``access_control`` section of every node of the rig: on every
    channel of the rig description, every role but its senders is denied
    the channel kind's messages."""
    rules: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for n, (suffix, channel, senders) in enumerate(sorted(RIG.expanded(), key=lambda item: item[0])):
        allowed = set(_senders(channel, senders, scenarios))
        others = [role for role in ROLES if role not in allowed]
        if not others:
            continue
        rule_id = f"{channel.kind} {n} {suffix}"
        rules.append(_rule(rule_id, _DENIED_MESSAGES[channel.kind], [f"{keys.root}/{suffix}"]))
        policies.append({"rules": [rule_id], "subjects": [f"role {role}" for role in others]})
    return {
        "enabled": True,
        "default_permission": "allow",
        "rules": rules,
        "subjects": [{"id": f"role {role}", "usernames": [role]} for role in ROLES],
        "policies": policies,
    }


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


def router_config(keys: Keys, credentials_file: str, listen: str = "tcp/0.0.0.0:7447", scenarios: bool = False) -> dict[str, Any]:
    """A zenoh router's configuration for the distributed rig (docker compose):
    authentication of every client, the rig's access rules, and (used by
    ``zenohd``, which has the plugins) the REST plugin on port 8000 with an
    in-memory storage of each rig's latest health and controller status, so
    ``curl http://localhost:8000/ralf/<rig>/health/**`` answers: a GET is a
    zenoh query, and health is published, not queryable, so the storage
    keeps the latest sample of every such key and answers for it."""
    return {
        "mode": "router",
        "listen": {"endpoints": [listen]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": credentials_file}}},
        "access_control": acl_config(keys, scenarios),
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


def insert_access(
    config: Any,
    rig_id: str,
    user: str = "",
    password: str = "",
    credentials_file: str = "",
    acl: bool = False,
    scenarios: bool = False,
    more_rigs: Iterable[str] = (),
) -> Any:
    """Add authentication and the rig's access rules to a ``zenoh.Config``
    (``more_rigs``: the rules of further rigs the same session serves, e.g.
    one DSP process for several rigs)."""
    if user or credentials_file:
        usrpwd: dict[str, str] = {}
        if user:
            usrpwd.update(user=user, password=password)
        if credentials_file:
            usrpwd["dictionary_file"] = credentials_file
        config.insert_json5("transport/auth/usrpwd", json.dumps(usrpwd))
    if acl:
        section = acl_config(Keys(rig_id), scenarios)
        for n, other in enumerate(r for r in more_rigs if r != rig_id):
            extra = acl_config(Keys(other), scenarios)
            for rule in extra["rules"]:
                rule["id"] = f"rig {n + 1} {rule['id']}"
            for policy in extra["policies"]:
                policy["rules"] = [f"rig {n + 1} {r}" for r in policy["rules"]]
            section["rules"] += extra["rules"]
            section["policies"] += extra["policies"]
        config.insert_json5("access_control", json.dumps(section))
    return config


def insert_access_from_env(config: Any, rig_id: str, env: Mapping[str, str]) -> Any:
    """:func:`insert_access` from ``RALF_ZENOH_*`` variables (e.g. a
    launcher's own session, configured like the services)."""
    return insert_access(
        config,
        rig_id,
        user=env.get("RALF_ZENOH_USER", ""),
        password=env.get("RALF_ZENOH_PASSWORD", ""),
        credentials_file=env.get("RALF_ZENOH_CREDENTIALS_FILE", ""),
        acl=env.get("RALF_ZENOH_ACL", "").lower() in ("1", "true", "yes", "on"),
        scenarios=env.get("RALF_ZENOH_ACL_SCENARIOS", "").lower() in ("1", "true", "yes", "on"),
    )


def role_env(role: str, credentials: Mapping[str, str]) -> dict[str, str]:
    """The variables that make a session authenticate as ``role``."""
    return {"RALF_ZENOH_USER": role, "RALF_ZENOH_PASSWORD": credentials[role]}
