"""The controller's can_conflict monitor in whole (one-process) runs: a rogue
SYNC producer on the rig's bus is reported, and policy ``stop`` ends the run;
forged plant frames (a second TPDO1 per SYNC, a heartbeat STOPPED, a conflict
EMCY) and a foreign SDO write are named with their evidence, stop the run
under the default policy, and (heartbeat, SDO write) leave it running under
``warn``."""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from typing import Any

import can
import pytest

import workbench.composition
from controller.plant_link import PlantLink
from protocol import can_map
from protocol.can_map import NmtState
from workbench.composition import InProcessRun, run_in_process


@pytest.mark.timeout(120)
def test_a_rogue_sync_producer_fires_can_conflict_and_policy_stop_ends_the_run(monkeypatch: pytest.MonkeyPatch) -> None:
    channels: list[str] = []
    opened = threading.Event()

    class SpiedLink(PlantLink):
        """Tells the rogue which virtual channel the run's bus is on."""

        def __post_init__(self) -> None:
            super().__post_init__()
            channels.append(self.bus.channel_id)  # type: ignore[attr-defined]
            opened.set()

    monkeypatch.setattr(workbench.composition, "PlantLink", SpiedLink)
    stop = threading.Event()

    def produce() -> None:  # a second SYNC producer, 50 Hz, at most 150 frames
        if not opened.wait(30.0):
            return
        rogue = can.Bus(interface="virtual", channel=channels[0])
        try:
            _produce(rogue)
        finally:
            rogue.shutdown()

    def _produce(rogue: can.BusABC) -> None:
        for k in range(150):
            if stop.wait(0.02):
                return
            rogue.send(can.Message(arbitration_id=can_map.SYNC_COB_ID, data=bytes([1 + k % 240]), is_extended_id=False))

    thread = threading.Thread(target=produce, daemon=True)
    thread.start()
    try:
        run = run_in_process(
            controller={"duration_s": 3.0, "policies": "can_conflict=stop", "tf_download_samples": 0},
        )
    finally:
        stop.set()
        thread.join(2.0)
    assert run.result.error is not None and run.result.error.startswith("stopped by monitor policy: can_conflict")
    assert "foreign sync" in run.result.error
    assert run.result.counters["foreign_sync"] >= 1
    assert run.controller.monitors.episodes["can_conflict"] >= 1
    assert run.result.ticks < 600


# --- forged plant frames and foreign SDO writes in whole runs (lockstep, one process) ------------

FORGED_WORDS = struct.pack("<4h", 32767, 32767, -32768, -32768)


def _attacked_run(monkeypatch: pytest.MonkeyPatch, controller: dict[str, Any], attack: Callable[[can.BusABC], None], at_tick: int = 50) -> InProcessRun:
    """A one-process lockstep run; ``attack(rogue)`` runs in the controller's loop before
    ``at_tick`` (the rig waits for it), ``rogue`` a station on the run's virtual channel."""
    links: list[PlantLink] = []
    rogues: list[can.BusABC] = []

    class SpiedLink(PlantLink):
        def __post_init__(self) -> None:
            super().__post_init__()
            links.append(self)

    def act() -> None:
        rogues.append(can.Bus(interface="virtual", channel=links[0].bus.channel_id))  # type: ignore[attr-defined]
        attack(rogues[0])

    monkeypatch.setattr(workbench.composition, "PlantLink", SpiedLink)
    try:
        return run_in_process(controller={"duration_s": 1.0, "tf_download_samples": 0, **controller}, at_tick=(at_tick, act))
    finally:
        for rogue in rogues:
            rogue.shutdown()


@pytest.mark.timeout(120)
def test_a_forged_tpdo1_answering_every_sync_stops_the_run_by_default(monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: forged full-scale words were used in 1,974 of 2,001 ticks, in silence.
    Now the default policy ends the run once the plant's own answer shows the second
    TPDO1 (lockstep runs on the forged answers meanwhile: how many ticks that takes is
    the host's scheduling, so the bound is only "before the run's end"), naming it."""
    stop = threading.Event()

    def attack(rogue: can.BusABC) -> None:
        def answer() -> None:  # answers every SYNC with full-scale words, at most 400 frames
            for _ in range(400):
                msg = rogue.recv(0.5)
                if stop.is_set():
                    return
                if msg is not None and msg.arbitration_id == can_map.SYNC_COB_ID:
                    rogue.send(can.Message(arbitration_id=can_map.TPDO1_BASE + 1, data=FORGED_WORDS, is_extended_id=False))

        threading.Thread(target=answer, daemon=True).start()

    try:
        run = _attacked_run(monkeypatch, {"duration_s": 2.0}, attack)
    finally:
        stop.set()
    assert run.result.error is not None and run.result.error.startswith("stopped by monitor policy: can_conflict")
    assert ("surplus tpdo1" in run.result.error and "ff 7f ff 7f 00 80 00 80" in run.result.error) or (
        "impersonation: the plant reports a frame id 0x181" in run.result.error
    )
    assert run.result.counters["surplus_tpdos"] + run.result.counters["impersonations"] >= 1
    assert 50 <= run.result.ticks < 400  # stopped after the attack began, before the run's end


@pytest.mark.timeout(120)
@pytest.mark.parametrize("policy", ["stop", "warn"])
def test_a_spoofed_stopped_heartbeat_is_diagnosed_as_a_forgery(monkeypatch: pytest.MonkeyPatch, policy: str) -> None:
    """Before: two spoofed heartbeats ended the run with "plant node left OPERATIONAL"
    while the plant ran. Now it is a conflict under the policy: stop names the
    forgery; warn runs to the end."""

    def attack(rogue: can.BusABC) -> None:
        rogue.send(can.Message(arbitration_id=can_map.HEARTBEAT_BASE + 1, data=bytes([NmtState.STOPPED]), is_extended_id=False))

    run = _attacked_run(monkeypatch, {"policies": {"can_conflict": policy}}, attack)
    assert run.result.counters["forged_heartbeats"] == 1
    if policy == "stop":
        assert run.result.error is not None and "forged heartbeat: heartbeat STOPPED id 0x701 [04]" in run.result.error
    else:
        assert run.result.error is None and run.result.ticks == 200
        assert run.controller.monitors.episodes["can_conflict"] >= 1


@pytest.mark.timeout(120)
def test_a_forged_conflict_emcy_is_named_a_forgery(monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: one forged EMCY 0xFF02 under policy stop ended the run for a conflict that never happened."""

    def attack(rogue: can.BusABC) -> None:
        rogue.send(can.Message(arbitration_id=can_map.EMCY_BASE + 1, data=can_map.encode_emcy(can_map.EmcyCode.SYNC_CONFLICT, 0x81), is_extended_id=False))

    run = _attacked_run(monkeypatch, {}, attack)
    assert run.result.error is not None and "forged emcy: EMCY SYNC_CONFLICT" in run.result.error
    assert run.result.counters["conflict_emcys"] == 0 and run.result.counters["forged_emcys"] == 1


@pytest.mark.timeout(120)
@pytest.mark.parametrize("policy", ["stop", "warn"])
def test_a_foreign_heartbeat_time_write_is_named_or_undone(monkeypatch: pytest.MonkeyPatch, policy: str) -> None:
    """Before: one foreign SDO write 0x1017 = 0 ended the run as a lost heartbeat."""

    def attack(rogue: can.BusABC) -> None:
        rogue.send(can.Message(arbitration_id=can_map.SDO_RX_BASE + 1, data=bytes([0x2B, 0x17, 0x10, 0, 0, 0, 0, 0]), is_extended_id=False))

    run = _attacked_run(monkeypatch, {"policies": {"can_conflict": policy}}, attack)
    assert run.result.counters["foreign_sdo"] == 1 and run.result.counters["comm_restores"] == 1
    if policy == "stop":
        assert run.result.error is not None and "foreign sdo: a write of 0x1017:0 = 0" in run.result.error
    else:
        assert run.result.error is None and run.result.ticks == 200
