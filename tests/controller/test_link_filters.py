"""The controller's acceptance filters (controller.plant_link.link_can_filters)
are exactly the frames PlantLink reads: every standard identifier is offered
to the link, and those that change anything it keeps are the ones the
filters accept (python-can's own filter rule judges them)."""

from __future__ import annotations

import copy
from collections.abc import Iterator

import can
import pytest

from controller.plant_link import PlantLink, link_can_filters
from protocol.settings import ControllerSettings
from service_kit.transport import open_can_bus


def _state(link: PlantLink) -> object:
    return (copy.deepcopy(link.counters), link.node_state, link.bootups, len(link.emergencies), link._sdo.response, link._pending_tpdo)


@pytest.fixture
def reference() -> Iterator[can.BusABC]:
    bus = can.Bus(interface="virtual", channel="link-filters-reference")
    yield bus
    bus.shutdown()


@pytest.mark.parametrize("node_id", [1, 5])
@pytest.mark.parametrize("data", [bytes(8), bytes([0x05, 0x7F, 1, 2, 3, 4, 5, 6]), b"\x05"])
def test_the_link_reads_exactly_what_its_filters_accept(node_id: int, data: bytes, reference: can.BusABC) -> None:
    reference.set_filters(link_can_filters(node_id))
    bus = can.Bus(interface="virtual", channel=f"link-filters-{node_id}")
    try:
        link = PlantLink(bus, node_id)
        reads = set()
        for ident in range(0x800):
            before = _state(link)
            link._dispatch(can.Message(arbitration_id=ident, data=data, is_extended_id=False))
            if _state(link) != before:
                reads.add(ident)
        accepted = {i for i in range(0x800) if reference._matches_filters(can.Message(arbitration_id=i, is_extended_id=False))}
        assert reads == accepted
    finally:
        bus.shutdown()


def test_filters_are_set_only_where_the_arbiter_applies_them() -> None:
    bus = open_can_bus(ControllerSettings(can_interface="virtual", can_channel="link-filters-open"), consumes=link_can_filters(1))
    try:
        assert bus.filters is None  # virtual: every frame, as without them
    finally:
        bus.shutdown()
