"""Kinematics (Appendix A via protocol.geometry), the hydraulic lag and the hard stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from plant_emulator.model import PlantConfig, RalfArm
from plant_emulator.model import kinematics as kin

QUIET = dict(sensor_noise=False)


def test_forward_inverse_round_trip_over_the_workspace() -> None:
    g1, g2 = kin.workspace_grid(21, 56)
    x, y = kin.forward(g1, g2)
    t1, t2 = kin.inverse(x, y)
    assert np.allclose(t1, g1, atol=1e-9) and np.allclose(t2, g2, atol=1e-9)
    x2, y2 = kin.forward(t1, t2)
    assert np.allclose(x2, x, atol=1e-9) and np.allclose(y2, y, atol=1e-9)
    # the top edge of the workspace is the near-singular stretched arm
    assert np.all(np.abs(kin.jacobian_determinant(np.radians(10.0))) < 0.18 * kin.A1_IN * kin.A2_IN)


def test_extension_limits_are_the_joint_limits() -> None:
    for j in (0, 1):
        lo, hi = kin.extension_limits_in(j)
        cyl = kin.CYLINDERS[j]
        assert cyl.angle(lo) == pytest.approx(kin.JOINT_LIMITS_RAD[j][0], abs=1e-12)
        assert cyl.angle(hi) == pytest.approx(kin.JOINT_LIMITS_RAD[j][1], abs=1e-12)
        assert 0.0 <= lo < hi <= cyl.stroke_in
        th = np.linspace(*kin.JOINT_LIMITS_RAD[j], 50)
        slope = kin.lever_slope_in_per_rad2(cyl, th)
        num = np.gradient(np.asarray(cyl.lever_in_per_rad(th)), th)
        assert np.allclose(slope[1:-1], num[1:-1], rtol=1e-3)


def test_trajectory_sampler_and_home() -> None:
    tr = kin.sample_trajectory(dt_s=0.005)
    assert tr.t_s[-1] == pytest.approx(42.0, abs=0.01)  # 180 in at 5 in/s + 2 x 3 s pauses
    assert np.all(kin.within_limits(tr.theta1_rad, tr.theta2_rad))
    assert np.hypot(np.diff(tr.x_in), np.diff(tr.y_in)).max() == pytest.approx(5.0 * 0.005, rel=1e-6)
    h = kin.home_theta()
    assert (tr.theta1_rad[0], tr.theta2_rad[0]) == pytest.approx(h)
    arm = RalfArm(PlantConfig(**QUIET))
    assert arm.truth().theta_rad == pytest.approx(h, abs=1e-12)
    assert arm.truth().rigid_tip_in == pytest.approx((-19.437, 196.612), abs=1e-6)


@pytest.mark.parametrize("tau", [0.01, 0.005])
def test_valve_lag_time_constant(tau: float) -> None:
    arm = RalfArm(PlantConfig(valve_time_constant_s=tau, **QUIET))
    gain = arm.cfg.valve_gain_in_per_s_per_v[0]
    arm.set_valve_voltages(np.array([0.2, 0.0]))
    t, v = [], []
    for _ in range(60):
        arm.advance(0.001)
        tr = arm.truth()
        t.append(tr.time_s)
        v.append(tr.cylinder_velocities_in_s[0])
    v_ss = 0.2 * gain
    va = np.array(v)
    assert va[-1] == pytest.approx(v_ss * (1 - math.exp(-0.06 / tau)), rel=1e-9)
    # the 63.2 % crossing is the time constant (to one internal step)
    t63 = t[int(np.argmax(va >= v_ss * (1 - math.exp(-1.0))))]
    assert abs(t63 - tau) <= 0.001 + 1e-12
    # log-linear fit of the approach to steady state
    slope = np.polyfit(np.array(t), np.log(1.0 - va / v_ss), 1)[0]
    assert -1.0 / slope == pytest.approx(tau, rel=1e-6)
    assert tau < 0.02  # thesis: steady velocity well within 20 ms


def test_flow_saturation_and_d2a_clip() -> None:
    arm = RalfArm(PlantConfig(**QUIET))
    arm.set_valve_voltages(np.array([25.0, -3.0]))  # the D/A cannot exceed 10 V
    assert arm.truth().valve_volts == (10.0, -3.0)
    arm.advance(0.2)
    v = arm.truth().cylinder_velocities_in_s
    assert v[0] == pytest.approx(6.0, rel=1e-6) and v[1] == pytest.approx(-6.0, rel=1e-6)
    with pytest.raises(ValueError):
        arm.set_valve_voltages(np.array([0.0, float("nan")]))
    with pytest.raises(ValueError):
        arm.set_valve_voltages(np.zeros(3))


def test_hard_stops_are_enforced_and_reported() -> None:
    arm = RalfArm(PlantConfig(**QUIET))
    lo2 = kin.THETA2_LIMITS_RAD[0]
    hi1 = kin.THETA1_LIMITS_RAD[1]
    arm.set_valve_voltages(np.array([1.0, -1.0]))  # joint 1 up, joint 2 down: both into stops
    for _ in range(1600):  # 8 s at 200 Hz
        arm.advance(0.005)
        tr = arm.truth()
        assert kin.THETA1_LIMITS_RAD[0] - 1e-12 <= tr.theta_rad[0] <= hi1 + 1e-12
        assert lo2 - 1e-12 <= tr.theta_rad[1] <= kin.THETA2_LIMITS_RAD[1] + 1e-12
    tr = arm.truth()
    assert tr.at_stop == (1, -1)
    assert tr.theta_rad == pytest.approx((hi1, lo2), abs=1e-12)
    assert tr.theta_dot_rad_s == (0.0, 0.0) and tr.cylinder_velocities_in_s == (0.0, 0.0)
    assert tr.hard_stop_counts == (1, 1) and arm.hard_stop_count == 2
    ev = {e.joint: e for e in tr.hard_stop_events}
    assert ev[0].side == 1 and ev[1].side == -1 and ev[0].speed_in_s > 0.0
    # the bang rings the links
    assert max(abs(x) for x in tr.deflection_rates_in_s) > 0.0
    # pushing on does not count again; leaving and coming back does
    arm.advance(1.0)
    assert arm.hard_stop_count == 2
    arm.set_valve_voltages(np.array([0.0, 0.5]))
    arm.advance(0.5)
    assert arm.truth().at_stop == (1, 0)
    arm.set_valve_voltages(np.array([0.0, -0.5]))
    arm.advance(3.0)
    assert arm.truth().hard_stop_counts == (1, 2)
    assert arm.truth().as_dict()["hard_stop_count"] == 3


def test_home_without_the_waypoint_file(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """An installed package may lack protocol/trajectories: the plant still starts."""
    from plant_emulator.model import arm as arm_mod

    expected = kin.home_theta()
    monkeypatch.setattr(kin, "TRAJECTORY_DIR", tmp_path)
    arm_mod.default_deflection_zero.cache_clear()
    try:
        assert kin.home_theta() == pytest.approx(expected, abs=1e-9)
        a = RalfArm(PlantConfig(**QUIET))
        assert a.truth().theta_rad == pytest.approx(expected, abs=1e-9)
        assert a.truth().sensed_deflections_in == pytest.approx((0.0, 0.0), abs=1e-12)
    finally:
        arm_mod.default_deflection_zero.cache_clear()
