"""Bringing the plant node up for a run (CiA 301 NMT and SDO), as
:meth:`controller.plant_link.PlantLink.start_node` does it: wait for the
node's heartbeat, reset its communication (so a rogue STOP or another
master's settings do not block this run), configure it by SDO, start it
and wait until its heartbeat says OPERATIONAL."""

from __future__ import annotations

import math
import threading
from typing import Protocol

from controller.plant_errors import PlantFault, StopRequested
from controller.plant_link_counters import PlantLinkCounters
from controller.sdo_client import SdoClient
from protocol.can_map import OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, OD_SAMPLE_PERIOD, OD_WATCHDOG_PERIODS, NmtCommand, NmtState


class PlantLink(Protocol):
    """What bringing the node up needs of :class:`controller.plant_link.PlantLink`."""

    node_id: int
    node_state: NmtState | None
    last_heartbeat: float | None
    bootups: int
    counters: PlantLinkCounters

    def _now(self) -> float: ...

    def poll(self, timeout: float = 0.0) -> None: ...

    def nmt(self, command: NmtCommand) -> None: ...


def wait_for_node(link: PlantLink, timeout: float, stop: threading.Event | None = None) -> NmtState:
    """Wait for the node's heartbeat (its boot-up or a periodic one)."""
    deadline = link._now() + timeout
    while link.last_heartbeat is None:
        if stop is not None and stop.is_set():
            raise StopRequested("stopped while waiting for the plant")
        remaining = deadline - link._now()
        if remaining <= 0:
            raise PlantFault(f"no heartbeat from plant node {link.node_id} within {timeout:.1f} s: is ralf-plant running on the same CAN channel?")
        link.poll(timeout=min(remaining, 0.1))
    assert link.node_state is not None
    return link.node_state


def reset_communication(link: PlantLink, timeout: float, stop: threading.Event | None = None) -> None:
    """NMT RESET_COMMUNICATION, then wait for the node's boot-up: whatever
    state an earlier (or a rogue) master left it in (STOPPED, a changed
    heartbeat or 0x1019), it is PRE-OPERATIONAL with its communication
    objects at their defaults afterwards. The application objects
    (0x2000-0x2FFF, 0x6000-) keep their values: the plant is not reset."""
    bootups = link.bootups
    link.nmt(NmtCommand.RESET_COMMUNICATION)
    link.counters.comm_resets += 1
    deadline = link._now() + timeout
    while link.bootups == bootups:
        if stop is not None and stop.is_set():
            raise StopRequested("stopped while resetting the plant node's communication")
        remaining = deadline - link._now()
        if remaining <= 0:
            raise PlantFault(f"plant node {link.node_id} did not boot up after NMT reset-communication within {timeout:.1f} s")
        link.poll(timeout=min(remaining, 0.05))


def configure_node(sdo: SdoClient, sample_period_s: float | None) -> dict[tuple[int, int], int]:
    """Read the objects the link relies on (0x1017, 0x1019, the watchdog
    periods) and, given a sample period, write it (0x2000, so plant, watchdog
    and controller agree on it) and RPDO1's event timer (0x1400 sub 5 = the
    SYNC watchdog time, so a foreign SYNC stream cannot keep the valves open
    if this controller freezes). Returns the values as configured."""
    configured = {key: sdo.read(*key) for key in ((0x1017, 0), (0x1019, 0), (OD_WATCHDOG_PERIODS, 0))}
    if sample_period_s is not None:
        period_us = round(sample_period_s * 1e6)
        sdo.write(OD_SAMPLE_PERIOD, 0, period_us)
        # RPDO1 is cyclic from here on: its event timer (deadline monitoring) = the SYNC watchdog time
        timer_ms = min(0xFFFF, math.ceil(configured[(OD_WATCHDOG_PERIODS, 0)] * sample_period_s * 1e3))
        sdo.write(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB, timer_ms, 2)
        configured[(OD_SAMPLE_PERIOD, 0)] = period_us
        configured[(OD_RPDO1_COMM, OD_RPDO_EVENT_TIMER_SUB)] = timer_ms
    return configured


def enter_operational(link: PlantLink, timeout: float, stop: threading.Event | None = None) -> None:
    """NMT START, then wait until the heartbeat says OPERATIONAL (START again
    past half the time when heartbeats come but say otherwise)."""
    deadline = link._now() + timeout
    link.nmt(NmtCommand.START)
    while link.node_state != NmtState.OPERATIONAL:
        if stop is not None and stop.is_set():
            raise StopRequested("stopped while starting the plant")
        remaining = deadline - link._now()
        if remaining <= 0:
            raise PlantFault(f"plant node {link.node_id} did not become operational (state {link.node_state})")
        link.poll(timeout=min(remaining, 0.05))
        if link.node_state != NmtState.OPERATIONAL and link.counters.heartbeats and remaining < timeout / 2:
            link.nmt(NmtCommand.START)
