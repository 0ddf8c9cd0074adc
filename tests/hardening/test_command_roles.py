"""Who may set which field: every role, with its own certificate and
password, sends every field of every kind of control message on its
channel's key to a rig configured as ``ralf-hil up --zenoh-acl scenarios``
configures it; what reaches the rig is exactly what the access rules
(service_kit.access) let that role send, and of the commands that reach
the controller its edge (controller.dsp_inbox) takes exactly the fields the
key takes (protocol.command_fields): the tool role only what ``ralf-hil
reconfigure`` offers, the test knobs only the tester on its own key.
Loopback only, scouting off, one burst of a few hundred small messages."""

from __future__ import annotations

import argparse
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pydantic import BaseModel

from controller.dsp_inbox import DspInbox
from protocol.command_fields import COMMAND_KEYS, COMMAND_KINDS, RECONFIGURE_FIELDS, TEST_KNOBS, changed_fields
from protocol.messages import ConfigChange, encode
from protocol.rig_description import RIG
from service_kit.access import ROLES, sends
from tests.hardening.zenoh_rig import PeerRig, attacker, wait_peers

pytestmark = pytest.mark.rig

POLE = {"frequency_hz": 3.5, "damping_ratio": 0.02, "magnitude": 1.0, "source": "arx", "confidence": 0.9}
VARIANTS: dict[str, list[dict[str, Any]]] = {
    "BlockFlag": [{"state": "empty", "next_batch_seq": 3, "fft_width": 256, "batch_size": 40, "emulated_latency_s": 0.5, "config_seq": 2}],
    "Interrupt": [
        {
            "version": 2,
            "batch_seq": 3,
            "poles": [POLE],
            "confidence": 0.9,
            "compute_time_s": 0.001,
            "emulated_latency_s": 0.5,
            "samples_in_history": 512,
            "valid_fraction": 0.5,
            "deadline_missed": True,
        }
    ],
    "ConfigChange": [
        {"fft_width": 256},
        {"batch_size": 40},
        {"alpha": 0.5},
        {"emulated_latency_s": 0.5},
        {"reset": True},
        {"request_id": "r1", "fft_width": 512},
    ],
    "ConfigAck": [{"request_id": "r1", "accepted": False, "reason": "no", "fft_width": 256, "batch_size": 40, "alpha": 0.5, "emulated_latency_s": 0.5}],
    "GroundTruth": [
        {
            "modal_frequencies_hz": [3.5],
            "damping_ratios": [0.02],
            "deflections_in": [0.1, 0.2],
            "theta_rad": [0.1, 0.2],
            "tip_in": [0.1, 0.2],
            "payload_attached": True,
            "valves_held": True,
        }
    ],
    "ChannelTruth": [
        {
            "ai_true_v": [1.0, 2.0, 3.0, 4.0],
            "ai_faulted_v": [1.0, 0.0, 3.0, 4.0],
            "ai_saturated": [False, True, False, False],
            "ao_time_s": 0.995,
            "ao_commanded_v": [0.5, -0.5],
            "ao_applied_v": [0.0, -0.5],
            "active_faults": ["AI2 short_ground from 0.5 s"],
        }
    ],
    "ScenarioCommand": [
        {"kind": "payload", "payload_attached": True, "at_sim_time_s": 5.0},
        {"kind": "seed", "seed": 7},
        {"kind": "adc_bits", "adc_bits": 16},
        {"kind": "channel_fault", "channel_fault": {"channel": "AI3", "kind": "short_ground", "start_s": 900.0}},
    ],
    "PlantEvent": [{"kind": "watchdog", "detail": "tripped"}],
    "ControllerStatus": [
        {
            "ticks": 5,
            "loop_rate_hz": 200.0,
            "batches_sent": 1,
            "interrupts": 1,
            "latest_frequency_hz": 3.5,
            "deadline_misses": 1,
            "overruns": 1,
            "finished": True,
        }
    ],
    "ParamSet": [{"request_id": "r1", "name": "controller.kp1", "value": 8000.0}, {"request_id": "r2", "name": "plant.payload", "value": 1.0}],
    "ParamAnswer": [
        {"request_id": "r1", "name": "controller.kp1", "accepted": False, "reason": "no"},
        {"request_id": "r1", "name": "controller.kp1", "accepted": True, "value": 8000.0},
    ],
    "ParamChanged": [
        {"tick": 3, "kind": "param", "who": "tester", "fields": {"controller.kp1": 8000.0}},
        {"tick": 4, "kind": "schedule", "who": "schedule", "fields": {"plant.payload": 1.0}},
    ],
}
"""Per message kind, messages that between them set every field (checked below)."""


def messages() -> list[tuple[str, str, BaseModel]]:
    """``(key suffix, kind name, message)`` for every field of every JSON message kind of the rig's channels."""
    out = []
    for suffix, model in sorted(RIG_JSON.items()):
        for variant in VARIANTS[model.__name__]:
            out.append((suffix, model.__name__, model.model_validate({"seq": 0, "sim_time_s": 1.0, "wall_time_s": 2.0, **variant})))
    return out


RIG_JSON: dict[str, type[BaseModel]] = {
    c.suffix: c.payload for c in RIG.channels if c.kind == "publication" and isinstance(c.payload, type) and not c.per_service()
}


def test_the_variants_set_every_field_of_every_message_kind() -> None:
    for model in set(RIG_JSON.values()):
        covered = {"seq", "sim_time_s", "wall_time_s"}.union(*VARIANTS[model.__name__])
        assert covered == set(model.model_fields), (model.__name__, set(model.model_fields) - covered)


def test_the_tools_command_takes_exactly_what_reconfigure_offers() -> None:
    from workbench.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))  # noqa: SLF001 (argparse keeps its subparsers there)
    offered = {a.dest for a in sub.choices["reconfigure"]._actions} & set(ConfigChange.model_fields)  # noqa: SLF001
    assert offered == RECONFIGURE_FIELDS == COMMAND_KINDS["command"]
    assert TEST_KNOBS <= COMMAND_KINDS["test_command"] and not TEST_KNOBS & COMMAND_KINDS["command"]
    assert {suffix for suffix, _ in ((s, c) for s, c in RIG_JSON.items() if c is ConfigChange)} == {"dsp/config", *COMMAND_KEYS.values()}


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[PeerRig]:
    rig_id = f"acl-fields-{zlib.crc32(str(tmp_path_factory.getbasetemp()).encode()) % 100000}"
    started = PeerRig.start(rig_id, tmp_path_factory.mktemp("acl-fields"), acl="scenarios")
    try:
        yield started
    finally:
        started.close()


def _controller_takes(suffix: str, payload: bytes) -> bool:
    """Whether the controller's edge would queue this command (its own inbox, as the loop has it)."""
    kind = next(k for k, s in COMMAND_KEYS.items() if s == suffix)
    inbox = DspInbox(lambda seq: True, synchronous=True)
    inbox.on_port_event(kind, payload, 0.0)
    return len(inbox.events) == 1


@pytest.mark.parametrize("role", ROLES)
def test_every_field_of_every_message_from_every_role(rig: PeerRig, role: str) -> None:
    keys = rig.keys
    own = sends(keys, role, scenarios=True)["publication"]
    sent: dict[bytes, tuple[str, BaseModel]] = {}
    session = attacker(role, rig)
    try:
        wait_peers(session, len(rig.endpoints))
        for n, (suffix, _name, message) in enumerate(messages()):
            tagged = message.model_copy(update={"seq": 10_000 * (ROLES.index(role) + 1) + n})
            payload = encode(tagged)
            sent[payload] = (suffix, tagged)
            session.put(f"{keys.root}/{suffix}", payload)
        if own:  # its own first key: on the same link, after everything above
            marker = b"marker:" + role.encode()
            session.put(own[0], marker)
            assert rig.taps["launcher"].wait_for(own[0], marker), f"{role}'s own key never reached the launcher's node"
        else:
            replies = list(session.get(f"{keys.root}/marker/launcher", timeout=20.0))
            assert any(r.ok is not None for r in replies), "no marker reply"
    finally:
        session.close()
    got = {payload: key for key, kind, payload, _ in rig.taps["launcher"].got if kind == "sample:put" and payload in sent}
    taken_fields: set[str] = set()
    for payload, (suffix, message) in sent.items():
        key = f"{keys.root}/{suffix}"
        assert (payload in got) == (key in own), (role, suffix, message)
        if payload in got and suffix in COMMAND_KEYS.values() and _controller_takes(suffix, payload):
            assert isinstance(message, ConfigChange)
            taken_fields |= changed_fields(message)
    expected: frozenset[str] = {"tool": RECONFIGURE_FIELDS, "tester": RECONFIGURE_FIELDS | TEST_KNOBS}.get(role, frozenset())
    assert taken_fields == expected, (role, taken_fields)


def test_the_test_command_key_is_closed_without_scenarios(tmp_path: Path) -> None:
    """Under ``--zenoh-acl on`` nobody may send on the test command key, the tester included."""
    rig = PeerRig.start(f"acl-noknob-{zlib.crc32(str(tmp_path).encode()) % 100000}", tmp_path)
    try:
        assert all(rig.keys.controller_test_command not in sends(rig.keys, role)["publication"] for role in ROLES)
        session = attacker("tester", rig)
        try:
            wait_peers(session, len(rig.endpoints))
            session.put(rig.keys.controller_test_command, encode(ConfigChange(seq=1, sim_time_s=0.0, emulated_latency_s=10.0)))
            session.put(rig.keys.controller_command, b"marker")  # the tester's own key under --zenoh-acl on
            assert rig.taps["controller"].wait_for(rig.keys.controller_command, b"marker")
        finally:
            session.close()
        assert not [k for k, _, _, _ in rig.taps["controller"].got if k == rig.keys.controller_test_command]
    finally:
        rig.close()
