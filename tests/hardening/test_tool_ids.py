"""A tool's zenoh session always opens its links to the rig's nodes: its id
is greater than every node's (of two peers the greater id opens the link, and
only the accepting side checks credentials, so a node matches the tool to its
role). Held end to end by ``tests/live/test_live_rig.py::
test_ralf_hil_live_joins_a_rig_started_elsewhere``."""

from __future__ import annotations

import json
import re

import zenoh

from service_kit.access import generate_node_ids, insert_access, tool_node_id

ZENOH_ID = re.compile(r"^[1-9a-f][0-9a-f]{31}$")


def test_every_tool_id_is_above_every_node_id() -> None:
    nodes = [zid for _ in range(500) for zid in generate_node_ids().values()]
    tools = [tool_node_id() for _ in range(2000)]
    assert all(ZENOH_ID.match(z) for z in nodes + tools)
    assert max(int(z, 16) for z in nodes) < min(int(z, 16) for z in tools)
    little_endian = [bytes.fromhex(z)[::-1] for z in nodes], [bytes.fromhex(z)[::-1] for z in tools]
    assert max(little_endian[0]) < min(little_endian[1])  # the order of zenoh's stored bytes too


def _id(config: zenoh.Config) -> str | None:
    text = config.get_json("id")
    return json.loads(text) if text else None


def test_an_authenticated_session_that_is_no_node_gets_a_tool_id() -> None:
    zid = _id(insert_access(zenoh.Config(), "rig", user="tool", password="secret"))
    assert zid is not None and int(zid, 16) >= 0b11 << 126


def test_a_node_keeps_its_own_id() -> None:
    ids = generate_node_ids()
    assert _id(insert_access(zenoh.Config(), "rig", user="plant", password="secret", node_id=ids["plant"], node_ids=ids)) == ids["plant"]
