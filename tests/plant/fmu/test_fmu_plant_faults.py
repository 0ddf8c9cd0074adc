"""A failing FMU step, driven through the CANopen node: Discard, Error and a
NaN output each raise EMCY PLANT_MODEL_FAULT (decoded with cantools), hold
the last A/D samples, are counted in the plant's health, and never stop the
node answering SYNC; a step slower than the sample period (an injected
stopwatch) is counted as the plant's overrun. The faults are the FMU's own
(its fault_step/fault_kind parameters), not a mock."""

from __future__ import annotations

from pathlib import Path

import can
import cantools
import numpy as np
import pytest

from plant_emulator.fmu import FmuPlant
from plant_emulator.fmu.plant import FAULT_DISCARD, FAULT_ERROR, FAULT_NON_FINITE
from plant_emulator.node import CanopenNode
from plant_emulator.plant_factory import build_plant_model
from plant_emulator.service import PlantApplication, build_health, node_config
from protocol import can_map
from protocol.can_map import EmcyCode
from protocol.messages import PlantEvent
from protocol.settings import PlantSettings
from tests.plant.fmu.support import plant_settings, write_mapping

DBC = cantools.database.load_file(str(Path(can_map.__file__).with_name("ralf.dbc")))
FAULT_STEP = 40
DISCARD, ERROR, NAN = 1, 2, 3


class Rig:
    def __init__(self, fmu: Path, mapping: Path) -> None:
        self.settings = PlantSettings(clock="lockstep", can_interface="virtual", watchdog_periods=1000, **plant_settings(fmu, mapping))
        self.events: list[PlantEvent] = []
        self.app = PlantApplication(self.settings, arm=build_plant_model(self.settings), publish_event=self.events.append)
        self.node = CanopenNode(self.app, node_config(self.settings))
        self.app.set_fault = self.node.set_fault
        self.ids = can_map.cob_ids(self.settings.node_id)
        self.k = 0
        self.counter = 0
        self.node.handle(can.Message(arbitration_id=0, data=can_map.encode_nmt(can_map.NmtCommand.START, 1), is_extended_id=False), 0.0)

    def sync(self, volts: tuple[float, float] = (0.05, -0.04)) -> tuple[list[int], list[tuple[int, int, int]]]:
        """One SYNC and the RPDO1 after it: the TPDO1's four codes and the EMCYs (code, register, cause byte)."""
        self.counter = can_map.next_sync_counter(self.counter)
        t = self.k * self.settings.sample_period_s
        replies = self.node.handle(can.Message(arbitration_id=0x80, data=can_map.encode_sync(self.counter), is_extended_id=False), t)
        data, _ = can_map.volts_to_output_frame(np.array(volts) * np.sin(0.3 * self.k))
        self.node.handle(can.Message(arbitration_id=self.ids["rpdo1"], data=data, is_extended_id=False), t)
        self.k += 1
        (tpdo,) = [m for m in replies if m.arbitration_id == self.ids["tpdo1"]]
        raw = DBC.decode_message("TPDO1_AnalogInputs16", tpdo.data, scaling=False)
        emcys = []
        for m in replies:
            if m.arbitration_id == self.ids["emcy"]:
                e = DBC.decode_message("EMCY_Plant", m.data, decode_choices=False)
                emcys.append((int(e["EMCY_ErrorCode"]), int(e["EMCY_ErrorRegister"]), int(e["EMCY_Vendor"]) & 0xFF))
        return [int(raw[f"AI{i}"]) >> 4 for i in (1, 2, 3, 4)], emcys

    @property
    def plant(self) -> FmuPlant:
        assert isinstance(self.app.arm, FmuPlant)
        return self.app.arm


@pytest.fixture
def rig_with(two_mode_fmu: Path, tmp_path: Path):  # type: ignore[no-untyped-def]
    made: list[Rig] = []

    def make(kind: int) -> Rig:
        rig = Rig(two_mode_fmu, write_mapping(tmp_path, f"k{kind}.yaml", {"fault_step": FAULT_STEP, "fault_kind": kind}))
        made.append(rig)
        return rig

    yield make
    for rig in made:
        rig.app.close()


@pytest.mark.parametrize("kind", [DISCARD, NAN])
def test_a_discarded_or_nan_step_raises_emcy_holds_the_samples_and_clears(rig_with, kind: int) -> None:  # type: ignore[no-untyped-def]
    rig = rig_with(kind)
    before = [rig.sync() for _ in range(FAULT_STEP)]
    assert all(not emcys for _, emcys in before)
    codes, emcys = rig.sync()  # the FMU's step number FAULT_STEP fails
    cause = FAULT_DISCARD if kind == DISCARD else FAULT_NON_FINITE  # the EMCY's vendor byte 0
    assert emcys == [(int(EmcyCode.PLANT_MODEL_FAULT), emcys[0][1], cause)]
    assert emcys[0][1] & 0x01  # generic error bit of the error register
    assert codes == before[-1][0]  # the last good samples, held
    after, cleared = rig.sync()  # the next step is good: the reset EMCY (code 0) and fresh samples
    assert [c for c, _, _ in cleared] == [0]
    assert after != codes
    for _ in range(20):
        assert rig.sync()[1] == []
    health = build_health(0, rig.app, rig.node, None)
    name = "fmu_step_discards" if kind == DISCARD else "fmu_non_finite_outputs"
    assert health.counters[name] == 1
    assert health.counters["samples"] == FAULT_STEP + 22
    assert health.state == "running"
    assert [e.kind for e in rig.events if e.kind.startswith("model_fault")] == ["model_fault", "model_fault_cleared"]


def test_an_error_step_ends_the_fmu_but_not_the_node(rig_with) -> None:  # type: ignore[no-untyped-def]
    rig = rig_with(ERROR)
    last = [rig.sync() for _ in range(FAULT_STEP)][-1][0]
    codes, emcys = rig.sync()
    assert [(c, cause) for c, _, cause in emcys] == [(int(EmcyCode.PLANT_MODEL_FAULT), FAULT_ERROR)]
    assert codes == last
    steps = rig.plant.steps_done
    for _ in range(30):  # FMI allows no doStep after Error: none is made, the node keeps answering with the held samples
        codes, emcys = rig.sync()
        assert codes == last and emcys == []
    assert rig.plant.steps_done == steps and rig.plant.failed
    health = build_health(0, rig.app, rig.node, None)
    assert health.counters["fmu_step_errors"] == 1 and health.counters["samples"] == FAULT_STEP + 31
    assert health.state == "degraded" and health.last_miss is not None and "error" in health.last_miss
    assert rig.app.arm.time_s == pytest.approx((FAULT_STEP + 31) * rig.settings.sample_period_s)


def test_a_step_longer_than_the_period_is_the_plants_overrun(rig_with) -> None:  # type: ignore[no-untyped-def]
    rig = rig_with(0)
    for _ in range(10):
        rig.sync()
    clock = iter(np.arange(0.0, 100.0, 0.004))  # each stopwatch read 4 ms after the last: a step "takes" 4 ms ...
    rig.plant.stopwatch = lambda: float(next(clock))
    for _ in range(5):
        rig.sync()
    assert rig.plant.overruns == 0
    clock = iter(np.arange(0.0, 100.0, 0.006))  # ... then 6 ms, longer than the 5 ms period
    rig.plant.stopwatch = lambda: float(next(clock))
    for _ in range(7):
        _, emcys = rig.sync()
        assert emcys == []  # slow is not wrong: no EMCY, the samples are fresh
    health = build_health(0, rig.app, rig.node, None)
    assert health.counters["fmu_step_overruns"] == 7
    assert health.latencies["fmu_step"].max == pytest.approx(0.006)
    assert health.last_miss is not None and "longer than the 5 ms period" in health.last_miss
    assert health.latencies["sync_to_sample"].count == 22  # the step is inside the SYNC -> sample hop


def test_the_fmu_is_instantiated_once_and_freed_on_stop(two_mode_fmu: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A co-simulation leaves nothing behind: the plant's FMU instance (and the
    launcher-style check's throw-away one) terminated, freed, their files removed."""
    import tempfile

    from workbench.cosim import run_cosim

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    run = run_cosim(controller={"duration_s": 2.0}, plant=plant_settings(two_mode_fmu, write_mapping(tmp_path)))
    plant = run.plant.arm
    assert isinstance(plant, FmuPlant)
    assert plant.steps_done == 400 and plant.instance.closed
    assert list(scratch.iterdir()) == []
    plant.close()  # a second close is harmless
