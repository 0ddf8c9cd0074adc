"""The plant publishes a SYNC's ground truth after its TPDO1 (off the SYNC ->
TPDO1 path), and what it publishes is still that SYNC's state, whoever
flushes it: the node's runner after the answer, the next callback before the
arm moves on, or the service at its end."""

from __future__ import annotations

import numpy as np

from plant_emulator.service import PlantApplication
from protocol.messages import GroundTruth
from protocol.settings import PlantSettings


def _app(published: list[GroundTruth]) -> PlantApplication:
    settings = PlantSettings(clock="lockstep", truth_rate_hz=200.0, truth_record="unused")
    return PlantApplication(settings, publish_truth=published.append)


def test_the_truth_waits_for_the_answer_and_is_the_syncs_state() -> None:
    published: list[GroundTruth] = []
    app = _app(published)
    app.on_sync(0)
    at_sync = app.arm.time_s
    assert published == []  # not on the SYNC -> TPDO1 path
    app.flush_side_channels()  # the runner, once TPDO1 is on the bus
    assert [t.sim_time_s for t in published] == [at_sync]
    app.flush_side_channels()
    assert len(published) == 1  # once per SYNC


def test_the_next_callback_flushes_before_the_arm_moves_on() -> None:
    published: list[GroundTruth] = []
    app = _app(published)
    app.on_sync(0)
    at_sync, theta = app.arm.time_s, app.arm.truth().theta_rad
    app.on_outputs(np.array([2.0, -2.0]))  # the RPDO1: flushed first
    (truth,) = published
    assert truth.sim_time_s == at_sync and truth.theta_rad == (float(theta[0]), float(theta[1])) and not truth.valves_held
    app.on_sync(1)  # the arm moves one period under the new valves: a new truth, not the old one again
    app.on_watchdog(True)  # flushes SYNC 1's truth (valves not yet held) before holding them
    assert [t.sim_time_s for t in published] == [at_sync, app.arm.time_s] and not published[-1].valves_held


def test_the_last_syncs_truth_is_kept_at_the_end() -> None:
    published: list[GroundTruth] = []
    app = _app(published)
    for counter in range(3):
        app.on_sync(counter)
    app.flush_side_channels()  # what serve() and run_cosim do when they stop
    assert len(app.truth_log) == 3 and app.truth_log[-1].sim_time_s == app.arm.time_s
