"""PI joint control (thesis §4): windowed, gated, anti-windup integrator on a lagged integrating plant."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy import signal

from controller.pi import PIConfig, PIController

TS = 0.005


class LaggedIntegrator:
    """Velocity-controlled joints: theta' = G (v_lag + d), v_lag' = (u - v_lag) / tau (thesis §3, actuators).

    Integrated exactly over each sample period with the command held (zero-order hold).
    """

    def __init__(self, gain: np.ndarray, tau: float, offset_v: np.ndarray | float = 0.0, theta0: float = 0.0) -> None:
        self.g = np.asarray(gain, float)
        self.tau = tau
        self.d = np.broadcast_to(np.asarray(offset_v, float), self.g.shape).copy()
        self.theta = np.full(self.g.shape, theta0)
        self.v = np.zeros(self.g.shape)

    def step(self, u: np.ndarray, dt: float = TS) -> np.ndarray:
        a = np.exp(-dt / self.tau)
        # theta gains G * integral of (v(t) + d) with v(t) = u + (v0 - u) e^(-t/tau)
        self.theta = self.theta + self.g * ((u + self.d) * dt + (self.v - u) * self.tau * (1.0 - a))
        self.v = u + (self.v - u) * a
        return self.theta.copy()


def run(pi: PIController, plant: LaggedIntegrator, setpoint: np.ndarray, seconds: float) -> tuple[np.ndarray, np.ndarray]:
    n = int(round(seconds / TS))
    errors = np.zeros((n, pi.n_joints))
    outputs = np.zeros((n, pi.n_joints))
    theta = plant.theta.copy()
    for k in range(n):
        u = pi.update(setpoint, theta)
        errors[k] = pi.error
        outputs[k] = u
        theta = plant.step(u)
    return errors, outputs


def test_defaults_are_the_thesis_values() -> None:
    cfg = PIConfig()
    assert cfg.kp_mv_per_rad == (7500.0, 6250.0)
    assert cfg.ki_mv_per_rad == (5000.0, 4166.0)
    assert cfg.forgetting_factor == 1e-4
    assert cfg.integrate_threshold_rad == 0.04
    assert cfg.output_limit_v == 10.0
    assert cfg.integral_time_scaled is True
    assert cfg.integral_scale == TS
    assert PIConfig(integral_time_scaled=False).integral_scale == 1.0


def test_config_validation() -> None:
    with pytest.raises(ValidationError):
        PIConfig(kp_mv_per_rad=(1.0,), ki_mv_per_rad=(1.0, 2.0))
    with pytest.raises(ValidationError):
        PIConfig(kp_mv_per_rad=(-1.0, 1.0))
    with pytest.raises(ValidationError):
        PIConfig(unknown_field=1)


def test_step_response_converges_and_integral_removes_offset() -> None:
    """A step inside the gate on two joints with a valve offset: the integrator trims the error
    to the small residual the forgetting factor allows, e = lambda I / Ts with Ki I + Kp e = -d."""
    pi = PIController()
    offset = np.array([0.3, -0.2])
    plant = LaggedIntegrator(gain=np.array([0.5, 0.8]), tau=0.02, offset_v=offset)
    target = np.array([0.03, -0.02])
    errors, _ = run(pi, plant, target, 30.0)
    kp, ki = pi.config.kp_v_per_rad, pi.config.ki_v_per_rad
    lam = pi.config.forgetting_factor
    integral_ss = -offset / (ki + kp * lam / TS)
    e_ss = lam * integral_ss / TS
    np.testing.assert_allclose(errors[-1], e_ss, rtol=0.02, atol=2e-6)
    assert np.all(np.abs(errors[-1]) < 0.05 * np.abs(offset / kp))  # P alone would leave -d/Kp
    np.testing.assert_allclose(pi.integral, integral_ss, rtol=0.02)
    assert np.all(np.abs(errors[-400:]) < 2e-3)  # settled, no oscillation left


def test_large_step_no_integration_until_inside_gate() -> None:
    pi = PIController()
    plant = LaggedIntegrator(gain=np.array([0.5, 0.5]), tau=0.02)
    errors, _ = run(pi, plant, np.array([0.3, 0.3]), 0.2)
    assert np.all(np.abs(errors) > 0.04)
    np.testing.assert_array_equal(pi.integral, 0.0)
    errors, _ = run(pi, plant, np.array([0.3, 0.3]), 20.0)
    assert np.all(np.abs(errors[-1]) < 1e-4)
    assert np.all(pi.integrating)


def test_integrator_is_an_exponentially_windowed_sum() -> None:
    pi = PIController(PIConfig(kp_mv_per_rad=(0.0,), ki_mv_per_rad=(1.0,)))
    lam = pi.config.forgetting_factor
    e0 = 0.01
    n = 3000
    for _ in range(n):
        pi.step([e0])
    expected = TS * e0 * (1.0 - (1.0 - lam) ** n) / lam
    np.testing.assert_allclose(pi.integral, [expected], rtol=1e-12)
    # raw sum: the same without the Ts
    raw = PIController(PIConfig(kp_mv_per_rad=(0.0,), ki_mv_per_rad=(1.0,), integral_time_scaled=False))
    for _ in range(n):
        raw.step([e0])
    np.testing.assert_allclose(raw.integral, [expected / TS], rtol=1e-12)


def test_gate_stops_summing_but_window_keeps_forgetting() -> None:
    pi = PIController()
    pi.reset(integral=[0.2, -0.1])
    lam = pi.config.forgetting_factor
    for _ in range(100):
        pi.step([0.05, -0.041])  # both beyond 0.04 rad
    np.testing.assert_allclose(pi.integral, np.array([0.2, -0.1]) * (1.0 - lam) ** 100, rtol=1e-12)
    assert not pi.integrating.any()
    pi.step([0.04, 0.0])  # at the threshold: admitted
    assert pi.integrating.all()


def test_output_clipped_and_anti_windup_at_saturation() -> None:
    """A stalled joint (error held at 0.03 rad, inside the gate) with the raw sum: the output
    saturates quickly; with anti-windup the integral stops where the output meets the limit,
    so when the error reverses the output leaves saturation at once."""
    cfg = PIConfig(integral_time_scaled=False)
    pi = PIController(cfg)
    no_aw = PIController(cfg.model_copy(update={"anti_windup": False}))
    err = np.array([0.03, -0.03])
    for _ in range(2000):
        u = pi.step(err)
        u2 = no_aw.step(err)
    np.testing.assert_allclose(u, [10.0, -10.0])
    np.testing.assert_allclose(u2, [10.0, -10.0])
    assert pi.saturated.all() and pi.windup_limited.all() and not pi.integrating.any()
    kp, ki = cfg.kp_v_per_rad, cfg.ki_v_per_rad
    # the integral stops exactly where Kp e + Ki I reaches the limit
    limit_integral = (np.array([10.0, -10.0]) - kp * err) / ki
    np.testing.assert_allclose(pi.integral, limit_integral, rtol=1e-12)
    assert np.all(np.abs(no_aw.integral) > 20 * np.abs(limit_integral))
    # reverse the error: anti-windup leaves saturation on the first tick, the wound-up one does not
    u = pi.step(-err)
    u2 = no_aw.step(-err)
    assert np.all(np.abs(u) < 10.0)
    assert np.all(np.abs(u2) == 10.0)
    # saturated, but an error pulling back out of saturation is still integrated
    pi.reset(integral=[100.0, -100.0])
    pi.step([-0.01, 0.01])
    assert pi.saturated.all() and pi.integrating.all() and not pi.windup_limited.any()


def test_raw_sum_limit_cycles_on_a_lagged_integrator_time_scaled_settles() -> None:
    """The Routh argument of the module docstring: stable iff Kp/Ki' > tau (valve lag)."""
    target = np.array([0.02, 0.02])
    gains = np.array([0.5, 0.5])
    scaled = PIController()
    e_scaled, _ = run(scaled, LaggedIntegrator(gains, tau=0.02), target, 12.0)
    raw = PIController(PIConfig(integral_time_scaled=False))
    e_raw, _ = run(raw, LaggedIntegrator(gains, tau=0.02), target, 12.0)
    last = slice(-400, None)  # the last 2 s
    assert np.max(np.abs(e_scaled[last])) < 1e-4
    assert np.max(np.abs(e_raw[last])) > 0.01


def test_vectorised_equals_independent_joints() -> None:
    rng = np.random.default_rng(1)
    errs = rng.normal(0.0, 0.03, size=(500, 2))
    both = PIController()
    j1 = PIController(PIConfig(kp_mv_per_rad=(7500.0,), ki_mv_per_rad=(5000.0,)))
    j2 = PIController(PIConfig(kp_mv_per_rad=(6250.0,), ki_mv_per_rad=(4166.0,)))
    for e in errs:
        u = both.step(e)
        np.testing.assert_allclose(u, [j1.step(e[:1])[0], j2.step(e[1:])[0]], rtol=1e-12)


def test_reset_and_update_from_setpoint_and_measurement() -> None:
    pi = PIController()
    u = pi.update([1.0, 1.0], [0.99, 1.01])
    np.testing.assert_allclose(pi.error, [0.01, -0.01])
    assert u[0] > 0 > u[1]
    pi.reset()
    np.testing.assert_array_equal(pi.integral, 0.0)
    np.testing.assert_array_equal(pi.output_v, 0.0)
    with pytest.raises(ValueError):
        pi.step([np.nan, 0.0])


@settings(max_examples=50, deadline=None)
@given(
    st.lists(st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)), min_size=1, max_size=200),
    st.booleans(),
)
def test_output_always_within_da_range(errors: list[tuple[float, float]], time_scaled: bool) -> None:
    pi = PIController(PIConfig(integral_time_scaled=time_scaled, output_limit_v=5.0))
    for e in errors:
        u = pi.step(e)
        assert np.all(np.abs(u) <= 5.0)
        np.testing.assert_allclose(u, np.clip(pi.p_term_v + pi.i_term_v, -5.0, 5.0))


@pytest.mark.parametrize("time_scaled", [True, False])
def test_inside_the_gate_and_the_limits_the_pi_is_scipys_first_order_recursion(time_scaled: bool) -> None:
    """``I_k = (1 - lambda) I_{k-1} + s e_k`` is ``lfilter([s], [1, -(1 - lambda)], e)``;
    the output ``Kp e + Ki I`` to 1e-12 relative (the same arithmetic, another order)."""
    cfg = PIConfig(integral_time_scaled=time_scaled, output_limit_v=1e4)  # the raw sum grows 200x larger
    pi = PIController(cfg)
    rng = np.random.default_rng(3)
    errors = np.cumsum(rng.normal(0.0, 5e-4, (800, 2)), axis=0).clip(-0.03, 0.03)
    out = np.array([pi.step(e) for e in errors])
    integral = signal.lfilter([cfg.integral_scale], [1.0, -(1.0 - cfg.forgetting_factor)], errors, axis=0)
    assert np.abs(out).max() < cfg.output_limit_v  # never at the limit: anti-windup never cuts
    np.testing.assert_allclose(out, cfg.kp_v_per_rad * errors + cfg.ki_v_per_rad * integral, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(pi.integral, integral[-1], rtol=1e-12)


def test_gated_errors_count_as_zero_in_the_windowed_sum() -> None:
    """Errors beyond the gate add nothing; the sum still decays (the lfilter of the admitted errors)."""
    cfg = PIConfig(output_limit_v=1e6, anti_windup=False)
    pi = PIController(cfg)
    rng = np.random.default_rng(4)
    errors = rng.uniform(-0.08, 0.08, (500, 2))
    for e in errors:
        pi.step(e)
    admitted = np.where(np.abs(errors) <= cfg.integrate_threshold_rad, errors, 0.0)
    integral = signal.lfilter([cfg.integral_scale], [1.0, -(1.0 - cfg.forgetting_factor)], admitted, axis=0)
    np.testing.assert_allclose(pi.integral, integral[-1], rtol=1e-12)
