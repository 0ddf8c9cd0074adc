"""The deflection cameras sit on the links' roots: they see the bending, not the link turning on its actuator."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_emulator.model import PlantConfig, RalfArm, modes
from plant_emulator.model import kinematics as kin


def test_bending_share_is_the_series_spring_split() -> None:
    s = modes.DEFAULT_STRUCTURE
    t1, t2 = math.radians(80.0), math.radians(40.0)
    got = modes.bending_fractions(t1, t2)
    # one torque through two springs in series: the link bends tau/k_r, the actuator yields tau/k_act
    lever1_m = float(kin.CYLINDER1.lever_in_per_rad(t1)) * 0.0254
    k_act1 = s.cylinder1_stiffness_n_per_m * lever1_m**2
    k_act2 = s.bar_stiffness_n_per_m * (s.crank_radius_in * 0.0254 * math.sin(t2 + math.radians(s.crank_offset_deg))) ** 2
    for j, (kr, ka) in enumerate(((s.link1_root_stiffness_nm_per_rad, k_act1), (s.link2_root_stiffness_nm_per_rad, k_act2))):
        tau = 1.0
        assert got[j] == pytest.approx((tau / kr) / (tau / kr + tau / ka), rel=1e-9)


def test_link2_camera_sees_less_where_the_bar_is_soft() -> None:
    loop = kin.sample_trajectory(dt_s=0.1)
    fr = modes.bending_fractions(loop.theta1_rad, loop.theta2_rad)
    assert np.all((fr > 0.0) & (fr <= 1.0))
    top = loop.theta2_rad < math.radians(25.0)
    bottom = loop.theta2_rad > math.radians(60.0)
    assert fr[top, 1].max() < fr[bottom, 1].min()
    assert np.ptp(fr[:, 0]) < 0.05  # link 1: the cylinder's lever hardly changes


def test_sensed_deflection_is_the_bending_or_the_whole_tip() -> None:
    for cam in (True, False):
        arm = RalfArm(PlantConfig(sensor_noise=False, camera_on_link=cam, deflection_zero_in=(0.0, 0.0)))
        arm.set_valve_voltages(np.array([0.3, -0.4]))
        arm.advance(0.4)
        t = arm.truth()
        share = modes.bending_fractions(*t.theta_rad) if cam else np.ones(2)
        assert t.camera_deflections_in == pytest.approx(np.asarray(t.deflections_in) * share, rel=1e-9)
    # the linearised transfer functions carry the same share
    f = np.array([3.0, 5.0])
    h_cam = modes.frequency_response(1.4, 0.6, f)
    h_tip = modes.frequency_response(1.4, 0.6, f, camera_on_link=False)
    assert np.allclose(h_cam / h_tip, modes.bending_fractions(1.4, 0.6)[None, None, :])
