"""Scenario inputs: payload, seed and resolution at given times."""

from __future__ import annotations

import numpy as np
import pytest

from plant_emulator.model import PlantConfig, RalfArm
from plant_emulator.scenario import Scenario, ScenarioEvent, apply_event
from protocol.messages import ScenarioCommand


def test_events_apply_at_their_time() -> None:
    arm = RalfArm(PlantConfig(seed=1))
    sc = Scenario(
        [
            ScenarioEvent.payload(1.0, True),
            ScenarioEvent.resolution(1.5, 16),
            ScenarioEvent.payload(2.0, False),
            ScenarioEvent.reseed(2.5, 9),
        ]
    )
    f0 = arm.truth().modal_frequencies_hz
    trace = []
    for _ in range(600):  # 3 s at 200 Hz
        sc.advance(arm, 0.005)
        trace.append((arm.time_s, arm.payload_attached, arm.adc_bits))
    assert [round(t, 9) for t, _ in sc.applied] == [1.0, 1.5, 2.0, 2.5]
    assert not sc.pending
    attached = [t for t, p, _ in trace if p]
    assert min(attached) == pytest.approx(1.0) and max(attached) == pytest.approx(1.995)
    assert arm.adc_bits == 16
    assert arm.truth().modal_frequencies_hz == pytest.approx(f0)


def test_event_between_samples_lands_on_the_internal_grid() -> None:
    arm = RalfArm(PlantConfig())
    sc = Scenario([ScenarioEvent.payload(0.0123, True)])
    sc.advance(arm, 0.02)
    assert sc.applied[0][0] == pytest.approx(0.0123, abs=1e-9)
    assert arm.time_s == pytest.approx(0.02)


def test_payload_change_mid_run_is_deterministic() -> None:
    def run() -> np.ndarray:
        arm = RalfArm(PlantConfig(seed=2))
        sc = Scenario([ScenarioEvent.payload(0.5, True)])
        arm.set_valve_voltages(np.array([0.2, 0.1]))
        out = []
        for _ in range(200):
            sc.advance(arm, 0.005)
            out.append(arm.sample().codes)
        return np.array(out)

    assert np.array_equal(run(), run())


def test_from_the_test_port_command() -> None:
    cmd = ScenarioCommand(seq=0, sim_time_s=0.0, wall_time_s=0.0, kind="adc_bits", at_sim_time_s=3.0, adc_bits=20)
    ev = ScenarioEvent.from_command(cmd)
    assert ev.at_time_s == 3.0 and ev.adc_bits == 20
    arm = RalfArm()
    apply_event(arm, ev)
    assert arm.adc_bits == 20 and arm.sample().bits == 20
    with pytest.raises(ValueError):
        ScenarioEvent(kind="payload")
