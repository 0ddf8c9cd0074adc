"""A tip force on the links deflects them as the modal model's statics say:
``K beta = G + J^T F`` (thesis [2-1, 2-2] at rest), ``K`` the model's own
stiffness (:func:`plant_emulator.model.modes.coefficients`), ``J`` the tips'
displacements per link rotation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_emulator.model.arm import PlantConfig, RalfArm
from plant_emulator.model.arm_state import ArmState
from plant_emulator.model.kinematics import INCH
from plant_emulator.model.modes import L1_M, L2_M, coefficients


def _settled(arm: RalfArm, seconds: float) -> np.ndarray:
    arm.advance(seconds)
    return np.array(ArmState.read(arm._st).beta_rad)


@pytest.mark.parametrize(("force1", "force2"), [(25.0, 0.0), (0.0, 15.0), (-10.0, -30.0)])
def test_a_held_tip_force_moves_the_static_deflection_by_k_inverse_j_transpose_f(force1: float, force2: float) -> None:
    arm = RalfArm(PlantConfig(sensor_noise=False))
    before = _settled(arm, 2.0)
    arm.set_tip_forces(force1, force2)
    after = _settled(arm, 8.0)  # the first mode's envelope (zeta 0.09, ~4 Hz) has decayed by e^-18
    t1, t2 = ArmState.read(arm._st).theta_rad
    _, _, _, k11, k12, k22, *_ = coefficients(t1, t2)
    stiffness = np.array([[k11, k12], [k12, k22]], dtype=float)
    kappa = arm.cfg.structure.slope_transmission
    jacobian = np.array([[L1_M, 0.0], [L1_M * math.cos(t2) + kappa * L2_M, L2_M]])  # rows: the two tips; columns: beta1, beta2
    expected = np.linalg.solve(stiffness, jacobian.T @ np.array([force1, force2]))
    np.testing.assert_allclose(after - before, expected, rtol=1e-6, atol=1e-12)
    # the sign: a force towards increasing beta on a link's own tip deflects that link that way
    if force1 and not force2:
        assert after[0] - before[0] > 0
    if force2 and not force1:
        assert after[1] - before[1] > 0
    # and the truth reports the deflection of those rotations (in)
    w = arm.truth().deflections_in
    np.testing.assert_allclose(w, (after[0] * L1_M / INCH, after[1] * L2_M / INCH))


def test_releasing_the_force_returns_the_links_and_no_force_changes_nothing() -> None:
    a, b = RalfArm(PlantConfig(sensor_noise=False)), RalfArm(PlantConfig(sensor_noise=False))
    b.set_tip_forces(40.0, -20.0)
    b.advance(1.0)
    b.set_tip_forces(0.0, 0.0)
    a.advance(1.0)
    assert not np.array_equal(ArmState.read(a._st).beta_rad, ArmState.read(b._st).beta_rad)
    a.advance(12.0)
    b.advance(12.0)
    np.testing.assert_allclose(ArmState.read(b._st).beta_rad, ArmState.read(a._st).beta_rad, rtol=0, atol=1e-9)
    c = RalfArm(PlantConfig(sensor_noise=False))
    c.set_tip_forces(0.0, 0.0)
    c.advance(13.0)
    assert np.array_equal(np.asarray(ArmState.read(c._st).beta_rad), np.asarray(ArmState.read(a._st).beta_rad))
    with pytest.raises(ValueError, match="finite"):
        a.set_tip_forces(math.nan, 0.0)
