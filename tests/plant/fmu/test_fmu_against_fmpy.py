"""The FMU plant against FMPy's own simulation of the same FMU: a recorded
valve signal goes to the node as RPDO1 frames, the node's TPDO1 frames are
decoded with cantools from the project's DBC, and every A/D sample equals
``fmpy.simulate_fmu`` of the same FMU with the same (D/A-quantized) input,
converted by the mapping and quantized to 12 bits with numpy."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import can
import cantools
import fmpy
import numpy as np
import pytest

from plant_emulator.fmu.mapping import load_mapping
from plant_emulator.node import CanopenNode
from plant_emulator.plant_factory import build_plant_model
from plant_emulator.service import PlantApplication, node_config
from protocol import can_map
from protocol.settings import PlantSettings
from tests.plant.fmu.support import EXAMPLE_MAPPING, plant_settings

DBC = cantools.database.load_file(str(Path(can_map.__file__).with_name("ralf.dbc")))
SECONDS = 12.0


@pytest.fixture(scope="module")
def recorded_valves() -> np.ndarray:
    """Valve commands the controller sent to the built-in arm along the inspection loop (a co-simulation's record)."""
    from workbench.cosim import run_cosim

    run = run_cosim(controller={"duration_s": SECONDS, "oatf_mode": "adaptive"}, dsp={"fft_width": 512})
    record = run.controller.record
    return np.column_stack([record.column("u1_v"), record.column("u2_v")])


def _frame(arbitration_id: int, data: bytes) -> can.Message:
    return can.Message(arbitration_id=arbitration_id, data=data, is_extended_id=False)


def _through_the_node(fmu: Path, valves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A/D codes of each SYNC's TPDO1, and the D/A volts each RPDO1 carried (both decoded with cantools)."""
    settings = PlantSettings(clock="lockstep", can_interface="virtual", watchdog_periods=1000, **plant_settings(fmu, EXAMPLE_MAPPING))
    app = PlantApplication(settings, arm=build_plant_model(settings))
    node = CanopenNode(app, node_config(settings))
    ids = can_map.cob_ids(settings.node_id)
    h = settings.sample_period_s
    node.handle(_frame(can_map.NMT_COB_ID, can_map.encode_nmt(can_map.NmtCommand.START, settings.node_id)), 0.0)
    codes = np.empty((len(valves), 4), dtype=np.int64)
    applied = np.empty((len(valves), 2))
    counter = 0
    tpdo1 = DBC.get_message_by_name("TPDO1_AnalogInputs16")
    rpdo1 = DBC.get_message_by_name("RPDO1_AnalogOutputs16")
    try:
        for k, volts in enumerate(valves):
            counter = can_map.next_sync_counter(counter)
            replies = node.handle(_frame(can_map.SYNC_COB_ID, can_map.encode_sync(counter)), k * h)
            (tpdo,) = [m for m in replies if m.arbitration_id == ids["tpdo1"]]
            raw = tpdo1.decode(tpdo.data, scaling=False)
            codes[k] = [raw[f"AI{i}"] >> 4 for i in (1, 2, 3, 4)]  # 12-bit codes, left-justified in 16-bit words
            data, _ = can_map.volts_to_output_frame(volts)
            node.handle(_frame(ids["rpdo1"], data), k * h)
            decoded = rpdo1.decode(data)
            applied[k] = (decoded["AO1"], decoded["AO2"])
        assert node.counters.as_dict()["app_errors"] == 0
    finally:
        app.close()
    return codes, applied


def _reference(fmu: Path, applied: np.ndarray, h: float) -> np.ndarray:
    """FMPy's simulation of the FMU with the valve volts held over each sample
    period (a step at every period boundary), its outputs every period."""
    mapping = load_mapping(EXAMPLE_MAPPING)
    n = len(applied)
    # input held on [(k+1) h, (k+2) h) is the k-th RPDO's; 0 V over the first period
    held = np.vstack([np.zeros((1, 2)), applied])
    t_edges = np.arange(n + 1) * h
    rows: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)]
    for k in range(1, n + 1):
        rows.append((t_edges[k], *held[k - 1]))
        rows.append((t_edges[k], *held[k]))
    signal = np.array(rows, dtype=[("time", np.float64), ("u1", np.float64), ("u2", np.float64)])
    start: dict[str, Any] = {**mapping.parameters, **mapping.start, "seed": 0}
    outputs = [ch.variable for ch in mapping.outputs]
    result = fmpy.simulate_fmu(str(fmu), fmi_type="CoSimulation", start_values=start, input=signal, output=outputs, output_interval=h, stop_time=n * h)
    assert np.allclose(result["time"], np.arange(n + 1) * h)
    volts = np.column_stack([ch.scale * result[ch.variable] + ch.offset for ch in mapping.outputs])
    lsb = 20.0 / 4096
    return np.clip(np.rint(volts / lsb), -2048, 2047).astype(np.int64)[1:]  # the state after each period


def test_rig_ad_samples_equal_fmpy_simulate_fmu(two_mode_fmu: Path, recorded_valves: np.ndarray) -> None:
    codes, applied = _through_the_node(two_mode_fmu, recorded_valves)
    reference = _reference(two_mode_fmu, applied, 1.0 / 200.0)
    assert np.abs(applied).max() > 0.05  # the recorded signal moved the valves
    assert np.ptp(codes[:, 2]) > 20 and np.ptp(codes[:, 0]) > 50  # the cylinders moved and the links rang (in LSBs)
    assert not (np.abs(codes) >= 2047).any()  # inside the converters' range: no saturation hides a difference
    np.testing.assert_array_equal(codes, reference)
