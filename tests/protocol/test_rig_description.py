"""The one rig description against everything derived from it or meant to
agree with it: the key properties, the access rules, the launcher's order,
the compose file (parsed with PyYAML), the console scripts, the docs table."""

from __future__ import annotations

import inspect
import tomllib
from pathlib import Path
from typing import ClassVar

import pytest
import yaml

from protocol.keys import SERVICES, Keys
from protocol.rig_description import RIG, Channel, RigDescription, Service, json_models, keys_table, start_order, stop_order
from service_kit.access import ROLES, acl_config, publishers
from workbench.config_docs import KEYS_BEGIN, KEYS_END
from workbench.launcher import SERVICE_MODULES, START_ORDER, STOP_ORDER, RigPlan, free_tcp_ports

ROOT = Path(__file__).resolve().parents[2]
KEYS = Keys("desc")


def _key_properties() -> dict[str, str]:
    """Every key a :class:`Keys` property or per-service method spells, below the root."""
    out: dict[str, str] = {}
    for name, member in inspect.getmembers(Keys):
        if name.startswith("_") or name == "root" or name.endswith("_all"):
            continue
        if isinstance(member, property):
            out[name] = getattr(KEYS, name)
        elif callable(member):
            for service in SERVICES:
                out[f"{name}({service})"] = member(KEYS, service)
    return {name: key.removeprefix(KEYS.root + "/") for name, key in out.items()}


def test_every_key_is_a_declared_channel_and_back() -> None:
    spelled = set(_key_properties().values())
    declared = {suffix for suffix, _, _ in RIG.expanded()}
    assert spelled == declared


def test_services_agree_with_keys_and_launcher() -> None:
    assert set(SERVICES) == set(RIG.service_names)
    assert SERVICE_MODULES == {"dsp": "dsp_service", "plant": "plant_emulator", "controller": "controller"}
    assert START_ORDER == ("dsp", "plant", "controller") and STOP_ORDER == tuple(reversed(START_ORDER))
    for n, name in enumerate(START_ORDER):
        assert set(RIG.service(name).after) <= set(START_ORDER[:n]), f"{name} starts before what it needs"


def test_start_order_is_a_topological_sort_and_cycles_are_refused() -> None:
    rig = RigDescription(
        services=(Service("c", "c", "c", ("b",), ""), Service("a", "a", "a", (), ""), Service("b", "b", "b", ("a",), "")),
        tools=(),
        channels=(),
    )
    assert start_order(rig) == ("a", "b", "c") and stop_order(rig) == ("c", "b", "a")
    cyclic = RigDescription(services=(Service("a", "a", "a", ("b",), ""), Service("b", "b", "b", ("a",), "")), tools=(), channels=())
    with pytest.raises(ValueError, match="cycle"):
        start_order(cyclic)
    with pytest.raises(KeyError, match="no service"):
        RIG.service("gpu")


def test_every_sender_is_a_role_and_access_rules_follow_the_senders() -> None:
    for suffix, _channel, senders in RIG.expanded():
        assert set(senders) <= set(ROLES), suffix
        assert "{service}" not in suffix
    allowed = publishers(KEYS, scenarios=True)
    for suffix, channel, senders in RIG.expanded():
        if channel.kind == "publication":
            assert allowed[f"{KEYS.root}/{suffix}"] == senders
    assert publishers(KEYS)[KEYS.scenario] == ()
    config = acl_config(KEYS, scenarios=True)
    policy_of = {r: p["subjects"] for p in config["policies"] for r in p["rules"]}
    granted: dict[tuple[str, str], set[str]] = {}
    for rule in config["rules"]:
        if rule["flows"] == ["ingress"]:
            for role in (s.removeprefix("user ").removeprefix("certificate ") for s in policy_of[rule["id"]]):
                for key in rule["key_exprs"]:
                    for message in rule["messages"]:
                        granted.setdefault((key, message), set()).add(role)
    for suffix, channel, senders in RIG.expanded():
        messages = {"publication": ("put", "delete"), "queryable": ("declare_queryable", "reply"), "liveliness": ("liveliness_token",)}[channel.kind]
        for message in messages:
            assert granted[(f"{KEYS.root}/{suffix}", message)] == set(senders), (suffix, message)


def test_recorder_models_are_the_published_json_channels() -> None:
    models = json_models()
    assert "dsp/batch" not in models and "dsp/tf" not in models
    assert all(isinstance(RIG.channel(s), Channel) for s in models)
    assert {s for s, c, _ in RIG.expanded() if c.kind == "publication" and isinstance(c.payload, type) and not c.per_service()} == set(models)


def test_compose_file_follows_the_description() -> None:
    compose = yaml.safe_load((ROOT / "docker-compose.yml").read_text())
    services = compose["services"]
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    for service in RIG.services:
        spec = services[service.name]
        assert spec["command"] == [service.command], service.name
        assert scripts[service.command] == f"{service.module}.__main__:main"
        depends = set(spec.get("depends_on", []))
        assert set(service.after) <= depends, f"compose {service.name} must depend on {service.after}"
        assert depends - set(service.after) <= {"zenoh-router"}
        assert spec["environment"]["RALF_ZENOH_USER"] == service.name
    always = {name for name, spec in services.items() if not spec.get("profiles")}  # the live view is an opt-in profile
    assert always == set(RIG.service_names) | {"zenoh-router"}


def test_design_doc_holds_the_generated_keys_table() -> None:
    text = (ROOT / "docs" / "design.md").read_text()
    section = text.split(KEYS_BEGIN, 1)[1].split(KEYS_END, 1)[0]
    assert section == keys_table(), "regenerate it: python -c \"from workbench.config_docs import write_keys_table; write_keys_table('docs/design.md')\""


class _ReusingSockets:
    """Sockets of a kernel that hands out the lowest free port, a just-closed
    one included (Linux may hand a closed port out again at once)."""

    bound: ClassVar[set[int]] = set()

    def __init__(self, *args: object) -> None:
        self.port: int | None = None

    def bind(self, address: tuple[str, int]) -> None:
        self.port = next(p for p in range(50000, 60000) if p not in self.bound)
        self.bound.add(self.port)

    def getsockname(self) -> tuple[str, int]:
        assert self.port is not None
        return ("127.0.0.1", self.port)

    def close(self) -> None:
        self.bound.discard(self.port)  # type: ignore[arg-type]

    def __enter__(self) -> _ReusingSockets:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def test_a_local_plan_gives_every_listener_its_own_port(monkeypatch: pytest.MonkeyPatch) -> None:
    """The launcher's listener and each service's are distinct even when the
    kernel hands a closed port out again at once (drawn one socket at a time,
    a controller once failed on the launcher's port): every socket stays
    bound until all are chosen."""
    import workbench.launcher as launcher

    monkeypatch.setattr(launcher.socket, "socket", _ReusingSockets)
    plan = RigPlan.local("ports")
    ports = [plan.zenoh_port, *plan.service_ports.values()]
    assert len(set(ports)) == len(ports) == 1 + len(SERVICE_MODULES), ports
    assert len(set(free_tcp_ports(64))) == 64
    assert not _ReusingSockets.bound  # all closed again
