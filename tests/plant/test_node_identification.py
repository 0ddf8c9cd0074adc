"""The plant identified through its CAN node, as a user of the rig would see
it: broadband valve commands go out as RPDO1 frames, A/D words come back in
TPDO1 on each SYNC, and scipy (not the project's DSP code) estimates the 2x2
frequency response, whose peaks must match the plant's published ground truth."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest

from controller.engineering import measure
from plant_emulator.canopen_node import CanopenNode
from plant_emulator.model import PlantConfig, RalfArm
from plant_emulator.service import PlantApplication, node_config
from protocol import can_map
from protocol.settings import PlantSettings
from tests.plant.support import interior_peak_hz, mimo_h1

FS = 200.0
HOLD = (math.radians(85.0), math.radians(25.0))
KP = np.array([7.5, 6.25])


def _frame(arbitration_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


@pytest.fixture(scope="module")
def over_can() -> tuple[np.ndarray, np.ndarray, list[float]]:
    settings = PlantSettings(clock="lockstep", can_interface="virtual", watchdog_periods=1000)
    app = PlantApplication(settings, arm=RalfArm(PlantConfig(seed=5, home_theta_rad=HOLD)))
    node = CanopenNode(app, node_config(settings))
    ids = can_map.cob_ids(settings.node_id)
    node.handle(_frame(can_map.NMT_COB_ID, can_map.encode_nmt(can_map.NmtCommand.START, settings.node_id)), 0.0)
    rng = np.random.default_rng(11)
    n = int(150 * FS)
    u = np.empty((n, 2))
    y = np.empty((n, 2))
    counter = 0
    for k in range(n):
        counter = can_map.next_sync_counter(counter)
        replies = node.handle(_frame(can_map.SYNC_COB_ID, can_map.encode_sync(counter)), k / FS)
        tpdo = [m for m in replies if m.arbitration_id == ids["tpdo1"]]
        assert len(tpdo) == 1
        m = measure(can_map.decode_analog_inputs_16(tpdo[0].data))
        command = KP * (np.array(HOLD) - m.theta_rad) + 0.05 * rng.standard_normal(2)
        data, clipped = can_map.volts_to_output_frame(command)
        assert not clipped.any()
        node.handle(_frame(ids["rpdo1"], data), k / FS)
        u[k] = can_map.output_frame_to_volts(data)  # what the D/A really applied
        y[k] = m.deflection_in
    truth = list(app.arm.truth().modal_frequencies_hz)
    assert node.counters.as_dict()["malformed"] == 0
    return u, y, truth


def test_peaks_identified_through_the_node_match_the_ground_truth(over_can: tuple[np.ndarray, np.ndarray, list[float]]) -> None:
    u, y, f_true = over_can
    f, H = mimo_h1(u, y)
    mag = np.abs(H)
    band = (f > 1.0) & (f < 12.0)
    assert np.all(mag[band].max(axis=0) > 0.05 * mag[band].max())  # all four paths carry the modes
    for r in range(2):
        at = [np.argmin(abs(f - f_true[r])), np.argmin(abs(f - f_true[1 - r]))]
        i, j = np.unravel_index(np.argmax(mag[at[0]] / mag[at[1]]), (2, 2))
        assert interior_peak_hz(f, mag[:, i, j], 0.8 * f_true[r], 1.2 * f_true[r]) == pytest.approx(f_true[r], rel=0.02)
