"""A tool joins a rig started elsewhere with nothing but the run's ``tool.env``:
it listens on nothing (zenoh's peer default would be a plain-TCP listener on
every interface) and opens its links to every node itself, whatever its zenoh
id, so every node knows it by its certificate. Loopback only, scouting off."""

from __future__ import annotations

import json
import threading
import zlib
from pathlib import Path

import pytest
import zenoh

from protocol.settings import CommonSettings
from service_kit.transport import zenoh_config
from tests.hardening.zenoh_rig import PeerRig, settings_from_env, wait_peers

pytestmark = pytest.mark.rig


def test_a_peer_without_a_listen_endpoint_listens_on_nothing_and_opens_its_links() -> None:
    config = zenoh_config(CommonSettings(zenoh_connect="tcp/127.0.0.1:7447"))
    assert json.loads(config.get_json("listen/endpoints")) == []
    assert json.loads(config.get_json("scouting/gossip/autoconnect_strategy")) == {"peer": {"to_router": "always", "to_peer": "always"}}
    listening = zenoh_config(CommonSettings(zenoh_listen="tcp/127.0.0.1:7448"))
    assert json.loads(listening.get_json("listen/endpoints")) == ["tcp/127.0.0.1:7448"]
    assert json.loads(listening.get_json("scouting/gossip/autoconnect_strategy")) != {"peer": {"to_router": "always", "to_peer": "always"}}
    # peers that find each other by multicast scouting, without TLS, keep zenoh's own listener: two with none could not link
    scouting = zenoh_config(CommonSettings(zenoh_multicast_scouting=True))
    assert "tcp/[::]:0" in json.loads(scouting.get_json("listen/endpoints"))["peer"]


@pytest.mark.parametrize("zid", ["1", "ffffffffffffffffffffffffffffffff"])
def test_a_tool_with_the_runs_tool_env_reaches_every_node_whatever_its_id(tmp_path: Path, zid: str) -> None:
    rig = PeerRig.start(f"tool-links-{zlib.crc32(str(tmp_path).encode()) % 100000}", tmp_path)
    keys = rig.keys
    try:
        env = dict(line.split("=", 1) for line in (tmp_path / "tool.env").read_text().splitlines())
        config = zenoh_config(settings_from_env(env))
        config.insert_json5("id", json.dumps(zid))  # below every node's id, or above
        tool = zenoh.open(config)
        got = threading.Event()
        try:
            sub = tool.declare_subscriber(keys.controller_status, lambda s: got.set() if s.payload.to_bytes() == b"status" else None)
            wait_peers(tool, 4)  # the launcher and the three services
            for _ in range(200):  # until the subscription has reached the controller (bounded: 10 s)
                rig.sessions[2].put(keys.controller_status, b"status")
                tool.put(keys.controller_command, b"marker")
                if got.wait(0.05) and rig.taps["controller"].wait_for(keys.controller_command, b"marker", timeout=0.0):
                    break
            sub.undeclare()
        finally:
            tool.close()
        assert got.is_set(), "the controller's status never reached the tool"
        assert rig.taps["controller"].wait_for(keys.controller_command, b"marker", timeout=0.0), "the tool's command never reached the controller"
    finally:
        rig.close()
