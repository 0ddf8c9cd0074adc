"""The plant's compiled period (plant_emulator/model/period_kernel.py) against
solutions nobody here wrote: the cylinders' first-order lag in closed form,
the hard-stop arrival from that closed form and scipy's root finder, and the
flexible links at rest on the stops against scipy's ``solve_ivp``.

Tolerances: the cylinder and the links are stepped with exact per-step
solutions, so against the closed form only rounding remains (relative
1e-9 over hundreds of steps); against ``solve_ivp`` (DOP853, rtol 1e-12)
the integrator's error dominates (1e-7 of the ringing's amplitude)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
import scipy.optimize

from plant_emulator.model import kinematics as kin
from plant_emulator.model.arm import L1_M, L2_M, PlantConfig, RalfArm
from tests.plant.link_matrices import link_matrices


def _lag(e0: float, u: float, tau: float, t: float) -> tuple[float, float]:
    """tau v' = u - v, e' = v from rest at e0: (extension, velocity) at t."""
    decay = math.exp(-t / tau)
    return e0 + u * t - u * tau * (1.0 - decay), u * (1.0 - decay)


def test_cylinders_follow_the_first_order_lag_in_closed_form() -> None:
    cfg = PlantConfig(seed=1, sensor_noise=False)
    volts = (0.1, -0.08)  # below flow saturation, far from the stops over 0.3 s
    arm = RalfArm(cfg)
    e0 = arm.truth().extensions_in
    arm.set_valve_voltages(np.array(volts))
    for k in range(1, 61):
        arm.advance(0.005)
        truth = arm.truth()
        for j in (0, 1):
            u = cfg.valve_gain_in_per_s_per_v[j] * volts[j]
            assert abs(u) < cfg.max_cylinder_speed_in_per_s[j]
            e, v = _lag(e0[j], u, cfg.valve_time_constant_s, 0.005 * k)
            assert truth.extensions_in[j] == pytest.approx(e, rel=1e-9, abs=1e-12), (k, j)
            assert truth.cylinder_velocities_in_s[j] == pytest.approx(v, rel=1e-9, abs=1e-12), (k, j)
    assert truth.hard_stop_counts == (0, 0)


def test_a_saturated_cylinder_arrives_at_its_stop_when_the_closed_form_says() -> None:
    cfg = PlantConfig(seed=1, sensor_noise=False)
    arm = RalfArm(cfg)
    h, tau = cfg.internal_step_s, cfg.valve_time_constant_s
    e0 = arm.truth().extensions_in[0]
    hi = kin.extension_limits_in(0)[1]
    u = min(cfg.valve_gain_in_per_s_per_v[0] * 10.0, cfg.max_cylinder_speed_in_per_s[0])  # full scale: saturated flow
    arrival = scipy.optimize.brentq(lambda t: _lag(e0, u, tau, t)[0] - hi, 0.0, 60.0, xtol=1e-14)
    arm.set_valve_voltages(np.array([10.0, 0.0]))
    while arm.time_s < arrival + 0.1:
        arm.advance(0.005)
    (event,) = arm.truth().hard_stop_events
    # recorded at the end of the internal step in which the extension crossed the stop
    assert event.joint == 0 and event.side == 1
    assert arrival <= event.time_s < arrival + h + 1e-12
    assert event.speed_in_s == pytest.approx(_lag(e0, u, tau, event.time_s)[1], rel=1e-9)
    truth = arm.truth()
    assert truth.extensions_in[0] == hi and truth.cylinder_velocities_in_s[0] == 0.0 and truth.at_stop[0] == 1


def _both_on_stops(arm: RalfArm) -> None:
    arm.set_valve_voltages(np.array([10.0, -10.0]))
    for _ in range(2000):
        arm.advance(0.005)
        if all(arm.truth().at_stop):
            break
    assert all(arm.truth().at_stop)
    arm.advance(2 * arm.cfg.internal_step_s)  # past the arrival step: the joints rest, no acceleration


def _links_reference(arm: RalfArm, beta0: np.ndarray, rate0: np.ndarray, times: np.ndarray) -> Any:
    """M beta'' + C beta' + K beta = G at the resting configuration, C built from the
    M-orthonormal modes with the structure's damping ratios (thesis Ch. 3), by solve_ivp."""
    t1, t2 = arm.truth().theta_rad
    M, K, _, G = link_matrices(arm.cfg.structure, arm.payload_attached, t1, t2)
    lam, phi = scipy.linalg.eigh(K, M)  # ascending: mode 1 first, phi.T M phi = I
    zetas = np.array(arm.cfg.structure.damping_ratios[:2])
    C = M @ phi @ np.diag(2.0 * zetas * np.sqrt(lam)) @ phi.T @ M
    Minv = np.linalg.inv(M)

    def rhs(_t: float, y: np.ndarray) -> np.ndarray:
        return np.concatenate([y[2:], Minv @ (G - C @ y[2:] - K @ y[:2])])

    sol = scipy.integrate.solve_ivp(rhs, (0.0, times[-1]), np.concatenate([beta0, rate0]), method="DOP853", t_eval=times, rtol=1e-12, atol=1e-15)
    assert sol.success
    return sol.y[:2].T, np.linalg.solve(K, G)


def test_links_ringing_on_the_stops_match_solve_ivp() -> None:
    arm = RalfArm(PlantConfig(seed=1, sensor_noise=False))
    _both_on_stops(arm)
    scale = np.array([L1_M, L2_M]) / kin.INCH  # beta (rad) -> tip deflection (in)
    truth = arm.truth()
    beta0 = np.array(truth.deflections_in) / scale
    rate0 = np.array(truth.deflection_rates_in_s) / scale
    times = 0.005 * np.arange(1, 101)
    expected, static = _links_reference(arm, beta0, rate0, times)
    got = []
    for _ in times:
        arm.advance(0.005)
        got.append(np.array(arm.truth().deflections_in) / scale)
    amplitude = np.max(np.abs(np.array(got) - static))
    assert amplitude > 1e-3 * np.max(np.abs(static))  # the stop's jolt left the links ringing
    np.testing.assert_allclose(np.array(got), expected, rtol=0, atol=1e-7 * amplitude)
    assert arm.truth().theta_rad == truth.theta_rad  # the joints stayed on their stops


def test_noise_reaches_the_filters_two_deviates_per_step() -> None:
    """Sensor noise draws one pair of deviates per internal step, across the kernel's block refills."""
    cfg = PlantConfig(seed=7)
    arm = RalfArm(cfg)
    quiet = RalfArm(PlantConfig(seed=7, sensor_noise=False))
    steps = round(0.005 / cfg.internal_step_s)
    drawn = 0
    before = arm._noise._next
    for _ in range(400):
        for a in (arm, quiet):
            a.advance(0.005)
        now = arm._noise._next
        drawn += now - before if now >= before else now + len(arm._noise._block) - before
        before = now
    assert drawn == 400 * steps * 2
    assert arm.truth().sensed_deflections_in != quiet.truth().sensed_deflections_in
    assert arm.truth().deflections_in == quiet.truth().deflections_in  # the noise is the sensors', not the arm's
