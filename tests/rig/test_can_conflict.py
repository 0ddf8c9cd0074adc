"""The controller's can_conflict monitor in a whole (one-process) run: a rogue
SYNC producer on the rig's bus is reported, and policy ``stop`` ends the run."""

from __future__ import annotations

import threading

import can
import pytest

import workbench.composition
from controller.plant_link import PlantLink
from protocol import can_map
from workbench.composition import run_in_process


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
            controller={"duration_s": 3.0, "policy_can_conflict": "stop", "tf_download_samples": 0},
        )
    finally:
        stop.set()
        thread.join(2.0)
    assert run.result.error is not None and run.result.error.startswith("stopped by monitor policy: can_conflict")
    assert "foreign sync" in run.result.error
    assert run.result.counters["foreign_sync"] >= 1
    assert run.controller.monitors.episodes["can_conflict"] >= 1
    assert run.result.ticks < 600
