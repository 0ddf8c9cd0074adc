"""The plant node's acceptance filters (node_can_filters) lose it nothing:
every standard identifier is offered to the node, and a frame the filters
refuse (python-can's own rule judges them) is at most counted as another
node's or TIME; whatever the node answers or does lies within them."""

from __future__ import annotations

import copy
from collections import Counter
from collections.abc import Iterator

import can
import pytest

from plant_emulator.canopen_node import CanopenNode, NodeConfig, node_can_filters
from protocol import can_map
from tests.plant.support import FakeApp

COUNTED_ONLY = {"foreign", "time"}
"""rx kinds of frames the node only counts."""


def _state(node: CanopenNode) -> object:
    c = copy.deepcopy(node.counters)
    c.rx = Counter({k: v for k, v in c.rx.items() if k not in COUNTED_ONLY})
    return c, node.state


@pytest.fixture
def reference() -> Iterator[can.BusABC]:
    bus = can.Bus(interface="virtual", channel="node-filters-reference")
    yield bus
    bus.shutdown()


@pytest.mark.parametrize("node_id", [1, 9])
@pytest.mark.parametrize("data", [bytes(8), bytes([0x01, 0x00, 1, 2]), b"\x05"])
def test_the_node_loses_nothing_to_its_filters(node_id: int, data: bytes, reference: can.BusABC) -> None:
    reference.set_filters(node_can_filters(node_id))
    node = CanopenNode(FakeApp(), NodeConfig(node_id=node_id))
    node.poll(0.0)
    acts = set()
    for ident in range(0x800):
        before = _state(node)
        out = node.handle(can.Message(arbitration_id=ident, data=data, is_extended_id=False), 0.001 * ident)
        if out or _state(node) != before:
            acts.add(ident)
    accepted = {i for i in range(0x800) if reference._matches_filters(can.Message(arbitration_id=i, is_extended_id=False))}
    assert acts <= accepted
    ids = can_map.cob_ids(node_id)
    assert {ids["nmt"], ids["sync"], ids["rpdo1"], ids["sdo_rx"]} <= acts  # what it consumes acts, so the comparison saw something
