"""The compiled period (plant_emulator/model/_period_kernel.py) equals the
Python reference step (RalfArm._step) bit for bit: state, truth, readings,
hard-stop events and the noise stream, through hard stops, noise-block
refills, a payload change and the configurations without noise or cameras."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_emulator.model import _period_kernel
from plant_emulator.model.arm import PlantConfig, RalfArm


def _pair(cfg: PlantConfig) -> tuple[RalfArm, RalfArm]:
    ref = RalfArm(cfg)
    ref.compiled_steps = False
    return ref, RalfArm(cfg)


def _drive(ref: RalfArm, fast: RalfArm, periods: int, volts: np.ndarray) -> None:
    for k in range(periods):
        v = volts[k % len(volts)]
        for arm in (ref, fast):
            arm.set_valve_voltages(v)
            arm.advance(0.005 if k % 7 else 0.0047)  # a remainder now and then
            if k == periods // 2:
                arm.attach_payload(True)
        a, b = ref.truth().as_dict(), fast.truth().as_dict()
        assert a == b, k
        ra, rb = ref.sample(), fast.sample()
        assert np.array_equal(ra.codes, rb.codes) and np.array_equal(ra.values_in, rb.values_in)


@pytest.mark.parametrize(
    "cfg",
    [PlantConfig(seed=3), PlantConfig(seed=1, sensor_noise=False), PlantConfig(seed=2, camera_on_link=False)],
    ids=["default", "noiseless", "whole-tip camera"],
)
def test_compiled_period_equals_the_python_step(cfg: PlantConfig) -> None:
    rng = np.random.default_rng(5)
    pushes = np.repeat(np.array([[10.0, 10.0], [-10.0, -10.0], [10.0, -10.0]]), 250, axis=0)  # full scale: onto the stops
    volts = np.concatenate([pushes, rng.uniform(-3.0, 3.0, size=(100, 2))])
    ref, fast = _pair(cfg)
    _drive(ref, fast, len(volts), volts)
    assert ref.hard_stop_count >= 1 and ref.truth().hard_stop_events  # a stop was reached
    assert ref._noise._next == fast._noise._next  # the same deviates consumed


def test_both_implementations_run_without_numba_too() -> None:
    # the Python function behind the compiled one gives the same floats
    ref, fast = _pair(PlantConfig(seed=4))
    fast._advance_steps = _period_kernel.advance_steps_py
    _drive(ref, fast, 60, np.array([[3.0, -2.0], [-10.0, 10.0]]))
    assert math.isfinite(fast.truth().theta_rad[0])


def test_the_state_handed_between_the_compiled_and_the_python_step() -> None:
    """The compiled period keeps the state in its vector between calls (unpacked only when read):
    switching to the Python step and back, sampling without asking for the truth, gives the reference's readings."""
    ref, mixed = _pair(PlantConfig(seed=6))
    rng = np.random.default_rng(9)
    for k in range(300):
        v = rng.uniform(-4.0, 4.0, 2)
        mixed.compiled_steps = (k // 7) % 3 != 1  # runs of compiled periods, then Python ones
        for arm in (ref, mixed):
            arm.set_valve_voltages(v)
            arm.advance(0.005)
        ra, rb = ref.sample(), mixed.sample()
        assert ra.code_list == rb.code_list and ra.values_in.tolist() == rb.values_in.tolist(), k
        if k % 50 == 49:
            assert ref.truth().as_dict() == mixed.truth().as_dict(), k
    assert ref.truth().as_dict() == mixed.truth().as_dict()
