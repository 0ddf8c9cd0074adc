"""The §4.3 velocity-feedback arm: a linear closed-loop model of the flexible arm under the thesis's PI.

Model (continuous time, per joint ``i`` = 1, 2, ``phi`` the controlled joint
angle, rad)::

    phi_i'  = v_i                                      joint velocity (rad/s)
    tau v_i' = G_i u_i - v_i                           valve lag: velocity-controlled actuator
    q_j'' + 2 zeta w q_j' + w^2 q_j = -alpha_j         one flexible mode per link (base excitation)
    d_j = L_j q_j                                       link-tip deflection (in)

with ``u_i`` the PI's valve voltage (``controller.pi.PIController``, the
thesis's gains, held over each sample), ``tau`` = 12.5 ms (98 % of a step's
steady velocity after 4 tau = 50 ms, the thesis's bound), ``G_i`` = 2 rad/s
per volt (proportional loop crossover ``G Kp`` = 15 and 12.5 rad/s), the
mode at 5 Hz, ``zeta`` = 0.09, driven by the link's angular acceleration
``alpha_1 = phi_1''``, ``alpha_2 = phi_1'' + phi_2''`` (link 2's absolute
angle; the elbow's translation and the links' coupling are neglected), and
``L`` = 120.1 in, 120 in (participation factor 1).  The hydraulics
overpower the structure, so the deflection does not load the joints.  All
costs in % of the unfiltered run are independent of ``G``'s scale factor
``L`` and the participation factor; their absolute values are not.

Discretisation: the model is linear with a zero-order-hold input, so it is
discretised exactly (``scipy.signal.cont2discrete(..., 'zoh')``, i.e. the
matrix exponential of the augmented system); :meth:`SimulationModel.discrete`
with ``substeps`` gives the product of finer steps to compare.  The PI sees
the joint angle at tick ``k`` and its output acts over ``[k Ts, (k+1) Ts)``
(no computation delay).  :func:`simulate` runs many closed loops at once as
one vectorised system.

Noise: Simulink's band-limited white noise block (power ``P``, sample time
``t_c``) emits a fresh normal deviate of std ``sqrt(P / t_c)`` every ``t_c``
(:meth:`SimulationModel.noise`; docs/simulation-calibration.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from scipy.signal import cont2discrete

from controller.metrics import percent_of_baseline, rms_costs
from controller.oatf import OatfConfig, OatfFilter, robust_delay_s
from controller.pi import PIConfig, PIController
from protocol import geometry
from workbench.experiments.lib.design_costs import design_label

__all__ = ["SimulationModel", "gain_sweep", "simulate"]


@dataclass(frozen=True)
class SimulationModel:
    """Parameters of the §4.3 velocity-feedback model (see the module docstring)."""

    sample_period_s: float = 0.005
    mode_hz: float = 5.0
    mode_zeta: float = 0.09
    valve_lag_s: float = 0.0125
    velocity_gain_rad_s_per_v: tuple[float, float] = (2.0, 2.0)
    link_length_in: tuple[float, float] = (geometry.A1_IN, geometry.A2_IN)
    tip_speed_in_s: float = 5.0
    noise_power_rad2_s: float = 2e-9
    """Simulink band-limited white noise power ``P`` (rad^2 s): ``sqrt(P / 0.1 s)`` = 1.41e-4 rad, the thesis's std."""
    noise_sample_time_s: float = 0.005
    """The noise block's sample time (its correlation time): the model's sample period."""
    noise_quoted_sample_time_s: float = 0.1
    """Sample time at which the thesis's quoted std holds (the Simulink block's default)."""
    fixed_delay_s: float = 0.05
    fixed_delay_is_upper_bound: bool = True
    """Group 3/4: ``T1 = min(fixed_delay_s, pi/w_d)`` (True) or ``fixed_delay_s`` whatever the design (False)."""
    design_zeta: float = 0.09
    group4_design_zeta: float = 0.01

    @property
    def noise_std_rad(self) -> float:
        """Std of each noise sample: ``sqrt(P / t_c)`` (Simulink's band-limited white noise block)."""
        return math.sqrt(self.noise_power_rad2_s / self.noise_sample_time_s)

    @property
    def noise_quoted_std_rad(self) -> float:
        """The std the thesis quotes: ``sqrt(P / 0.1 s)``."""
        return math.sqrt(self.noise_power_rad2_s / self.noise_quoted_sample_time_s)

    def noise_facts(self, phi_variance: np.ndarray) -> dict[str, Any]:
        """The noise against the set-points' power: the std that would be 0.2 % of each joint's ``phi_variance``
        (the thesis's wording), the std used and the one quoted, and the noise power in % of the variance."""
        return {
            "noise_std_for_0.2pct_of_phi_variance_rad": np.sqrt(0.002 * phi_variance).tolist(),
            "noise_std_used_rad": self.noise_std_rad,
            "noise_quoted_std_rad": self.noise_quoted_std_rad,
            "noise_power_pct_of_phi_variance": (100 * self.noise_std_rad**2 / phi_variance).tolist(),
        }

    def describe(self, span: str, n: int, zoh_dev: float) -> str:
        """The model in one paragraph, for a run over ``span`` of ``n`` samples whose discretisation agreed with ten sub-steps to ``zoh_dev``."""
        ts = self.sample_period_s
        return (
            f"Both joints follow the inspection loop's joint set-points (φ, {self.tip_speed_in_s:g} in/s, {span}, "
            f"{n} samples at {1 / ts:g} Hz) through velocity-controlled actuators (v̇ = (G·u − v)/τ, τ = {1e3 * self.valve_lag_s:g} ms: "
            f"98 % of a step's velocity in {4e3 * self.valve_lag_s:g} ms; G = {self.velocity_gain_rad_s_per_v[0]:g} rad/s per V) under the thesis's PI "
            "(`controller.pi`, 7500/6250 mV/rad, 5000/4166 mV/(rad·s)). "
            f"Each link has one mode, {self.mode_hz:g} Hz, ζ = {self.mode_zeta:g}, driven by the link's angular acceleration (base excitation); "
            f"deflection = link length × modal coordinate (in). Exact zero-order-hold discretisation at {1 / ts:g} Hz "
            f"(`scipy.signal.cont2discrete`; ten sub-steps of Ts/10 agree to {zoh_dev:.1e}). "
            "Costs: `controller.metrics.rms_costs` (10-sample slope, 40-sample quadratic, §4.2.1), in % of the unfiltered run of the same group and noise draw."
        )

    def describe_noise(self, n_draws: int, phi_variance: np.ndarray) -> str:
        """The noise in one paragraph: Simulink's block, the thesis's quoted std, and its "0.2 % of the signal's power" against ``phi_variance``."""
        v = phi_variance
        return (
            f"Noise (groups 2–4): Simulink's band-limited white noise, power P = {self.noise_power_rad2_s:g} rad²·s at a sample time "
            f"t_c = {1e3 * self.noise_sample_time_s:g} ms: a fresh Gaussian value every t_c of std √(P/t_c) = {self.noise_std_rad:.3g} rad per joint, "
            f"added to the filtered set-points, {n_draws} draws (mean ± std below), the same draws for every design and group. "
            f"The thesis quotes the std as {self.noise_quoted_std_rad:.3g} rad, which is √(P/{self.noise_quoted_sample_time_s:g} s): the block's "
            f"value at its default sample time {self.noise_quoted_sample_time_s:g} s, not at the model's {1e3 * self.sample_period_s:g} ms. "
            f"It also calls the noise 0.2 % of the trajectory signal's power; our loop's φ variance is {v[0]:.3g} and {v[1]:.3g} rad², "
            f"of which 0.2 % would be a std of {math.sqrt(0.002 * v[0]):.2g} and {math.sqrt(0.002 * v[1]):.2g} rad, 13–25 times more than "
            "reproduces the thesis's rise of the unfiltered cost (see 'Calibration')."
        )

    def noise(self, rng: np.random.Generator, shape: tuple[int, int, int]) -> np.ndarray:
        """``(draws, n, joints)`` noise: a fresh normal deviate every ``t_c``, held in between (``t_c`` >= Ts)."""
        draws, n, joints = shape
        hold = max(1, int(round(self.noise_sample_time_s / self.sample_period_s)))
        w = self.noise_std_rad * rng.standard_normal((draws, -(-n // hold), joints))
        return np.repeat(w, hold, axis=1)[:, :n]

    def delay_s(self, design_hz: float, zeta: float) -> float:
        """Group 3/4's T1 for a design (see the module docstring)."""
        if self.fixed_delay_is_upper_bound:
            return min(self.fixed_delay_s, robust_delay_s(design_hz, zeta))
        return self.fixed_delay_s

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of ``x = [phi1, v1, phi2, v2, q1, q1', q2, q2']``, ``u = [u1, u2]``."""
        tau = self.valve_lag_s
        g1, g2 = self.velocity_gain_rad_s_per_v
        w = 2 * math.pi * self.mode_hz
        z = self.mode_zeta
        a = np.zeros((8, 8))
        b = np.zeros((8, 2))
        a[0, 1] = a[2, 3] = 1.0
        a[1, 1] = a[3, 3] = -1.0 / tau
        b[1, 0], b[3, 1] = g1 / tau, g2 / tau
        # accelerations of the joints: v_i' = (G_i u_i - v_i) / tau
        acc1_a, acc1_b = a[1].copy(), b[1].copy()
        acc2_a, acc2_b = a[3].copy(), b[3].copy()
        for j, (qa, qb) in enumerate(((acc1_a, acc1_b), (acc1_a + acc2_a, acc1_b + acc2_b))):
            iq = 4 + 2 * j
            a[iq, iq + 1] = 1.0
            a[iq + 1] = -qa
            b[iq + 1] = -qb
            a[iq + 1, iq] += -w * w
            a[iq + 1, iq + 1] += -2 * z * w
        return a, b

    def discrete(self, substeps: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Exact ZOH discretisation at ``Ts`` (or the product of ``substeps`` ZOH steps of ``Ts/substeps``)."""
        a, b = self.continuous()
        h = self.sample_period_s / substeps
        ad, bd, *_ = cont2discrete((a, b, np.eye(8), np.zeros((8, 2))), h, method="zoh")
        ad_n, bd_n = np.eye(8), np.zeros((8, 2))
        for _ in range(substeps):
            ad_n, bd_n = ad @ ad_n, ad @ bd_n + bd
        return ad_n, bd_n


def simulate(model: SimulationModel, setpoints: np.ndarray, progress: Callable[[int], Any] | None = None, log_substeps: int = 1) -> dict[str, np.ndarray]:
    """Run ``R`` closed loops at once: ``setpoints`` is ``(R, n, 2)``; returns deflection ``(R, n, 2)`` (in) and more.

    ``log_substeps`` > 1 also logs the deflection ``log_substeps`` times per sample period
    (``deflection_fine_in``, ``(R, n * log_substeps, 2)``; exact ZOH sub-steps, the control at ``Ts``)."""
    r_runs, n, _ = setpoints.shape
    ad, bd = model.discrete()
    adt, bdt = ad.T.copy(), bd.T.copy()
    pi_cfg = PIConfig(sample_period_s=model.sample_period_s)
    pi = PIController(
        PIConfig(
            kp_mv_per_rad=pi_cfg.kp_mv_per_rad * r_runs,
            ki_mv_per_rad=pi_cfg.ki_mv_per_rad * r_runs,
            sample_period_s=model.sample_period_s,
        )
    )
    x = np.zeros((r_runs, 8))
    x[:, 0] = setpoints[:, 0, 0]
    x[:, 2] = setpoints[:, 0, 1]
    length = np.asarray(model.link_length_in)
    ac, bc = model.continuous()
    # rows of the continuous model that give the modal accelerations q1'', q2'' (the state's own derivative)
    acc_a, acc_b = ac[(5, 7), :].T.copy(), bc[(5, 7), :].T.copy()
    defl = np.empty((r_runs, n, 2))
    rate = np.empty((r_runs, n, 2))
    accel = np.empty((r_runs, n, 2))
    joints = np.empty((r_runs, n, 2))
    volts = np.empty((r_runs, n, 2))
    sp = np.ascontiguousarray(setpoints.transpose(1, 0, 2).reshape(n, 2 * r_runs))
    sub = int(log_substeps)
    fine = np.empty((r_runs, n * sub, 2)) if sub > 1 else None
    if sub > 1:
        ah, bh, *_ = cont2discrete((ac, bc, np.eye(8), np.zeros((8, 2))), model.sample_period_s / sub, method="zoh")
        aht, bht = ah.T.copy(), bh.T.copy()
    chunk = max(1, n // 50)
    for k in range(n):
        joints[:, k] = x[:, (0, 2)]
        defl[:, k] = x[:, (4, 6)] * length
        rate[:, k] = x[:, (5, 7)] * length
        u = pi.update(sp[k], x[:, (0, 2)].ravel()).reshape(r_runs, 2)
        volts[:, k] = u
        accel[:, k] = (x @ acc_a + u @ acc_b) * length
        if fine is None:
            x = x @ adt + u @ bdt
        else:
            for j in range(sub):
                fine[:, k * sub + j] = x[:, (4, 6)] * length
                x = x @ aht + u @ bht
        if progress is not None and (k + 1) % chunk == 0:
            progress(chunk)
    out = {"deflection_in": defl, "deflection_rate_in_s": rate, "deflection_accel_in_s2": accel, "joint_rad": joints, "valve_v": volts}
    if fine is not None:
        out["deflection_fine_in"] = fine
    return out


def gain_sweep(model: SimulationModel, ref: np.ndarray, designs: Sequence[float | None], gains: tuple[float, ...]) -> dict[str, dict[str, Any]]:
    """The loop ``ref`` through each of ``designs`` (OATF at the outer location, robust delay; the first None: unfiltered)
    for other actuator gains G: under each OATF design's label its velocity and
    acceleration cost in % of unfiltered (link 1, link 2), and the unfiltered velocity cost and tracking error."""
    cfg = OatfConfig(sample_period_s=model.sample_period_s, design_zeta=model.design_zeta)
    sps = [ref if f is None else OatfFilter([f], 2, cfg, initial=ref[0]).process(ref) for f in designs]
    out: dict[str, dict[str, Any]] = {}
    for g in gains:
        res = simulate(replace(model, velocity_gain_rad_s_per_v=(g, g)), np.stack(sps))
        c = [rms_costs(res["deflection_in"][i], model.sample_period_s) for i in range(len(designs))]
        row: dict[str, Any] = {}
        for f, ci in zip(designs[1:], c[1:]):
            p = percent_of_baseline(ci, c[0])
            row[design_label(f)] = {"velocity_pct": p.velocity_rms.tolist(), "acceleration_pct": p.acceleration_rms.tolist()}
        row["unfiltered_velocity_rms_in_s"] = c[0].velocity_rms.tolist()
        row["tracking_error_rms_rad"] = np.sqrt(np.mean((ref - res["joint_rad"][0]) ** 2, axis=0)).tolist()
        out[f"{g:g}"] = row
    return out
