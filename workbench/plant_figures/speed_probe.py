"""Why the emulated arm vibrates less at 4 in/s than at 5 in/s: candidate mechanisms, measured.

The thesis's unfiltered battery runs (Table 4-1 row a) vibrate 1.29–1.37 times
*more* at 4 in/s than at 5 in/s; the emulation 0.75–0.80 times as much.
``ralf-hil plant speed-probe`` runs the four unfiltered groups
(``report.closed_loop``: one lap from rest under the thesis's PI at 200 Hz, the
deflections as the A/D reads them, the §4.2.1 velocity cost) for the model as
it is and for what-if variants of the mechanisms that could make the vibration
depend on the speed other than in proportion to it, and prints, per variant,
each group's RMS deflection velocity against the thesis's and the ratio
4 in/s / 5 in/s per payload state and link.

Reference for the ratio: a linear plant driven by the corners alone gives
``(4/5) * sqrt(T_lap(5) / T_lap(4))`` = 0.726 (each corner's ring carries
energy ∝ v², the lap has the same corners at both speeds and lasts 42 s and
51 s); docs/plant-model.md explains the variants and the result.

The variants are probes, not the model: the valve shapes act on the PI's
output (a deadband, a stick/breakaway) rather than inside the plant, which is
equivalent for a velocity-source joint.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from controller.metrics import deflection_velocity, rms_costs
from plant_emulator.model import kinematics as kin
from plant_emulator.model.arm import PlantConfig, RalfArm
from workbench.plant_figures.report import FS, INTEGRATOR_WINDOW_RAD, KI, KP, THESIS_UNFILTERED, closed_loop

FloatArray = npt.NDArray[np.float64]
SPEEDS = (5.0, 4.0)
PAYLOADS = (True, False)


def deadband(width_v: float) -> Callable[[FloatArray], FloatArray]:
    """A valve with spool overlap: no flow within ±``width_v``, the flow gain unchanged beyond."""

    def shape(u: FloatArray) -> FloatArray:
        return np.sign(u) * np.maximum(np.abs(u) - width_v, 0.0)

    return shape


def breakaway(threshold_v: float) -> Callable[[FloatArray], FloatArray]:
    """Stick-slip: a resting cylinder starts only when the command exceeds
    ``threshold_v`` (static friction), then follows it until the command falls
    below half of that (Coulomb friction lower than static), and sticks again."""
    moving = np.zeros(2, dtype=bool)

    def shape(u: FloatArray) -> FloatArray:
        nonlocal moving
        moving = np.where(moving, np.abs(u) > 0.5 * threshold_v, np.abs(u) > threshold_v)
        return np.where(moving, u, 0.0)

    return shape


@dataclass(frozen=True)
class Variant:
    """One what-if variant of the unfiltered loop."""

    name: str
    what: str
    config: dict[str, Any] = field(default_factory=dict)
    """PlantConfig overrides (seed and payload are the group's)."""
    blend_s_at_5: float = 0.0
    """Set-point smoothing window at 5 in/s."""
    blend_scales_with_speed: bool = False
    """True: window ∝ speed (a fixed acceleration limit at the corners); False: fixed."""
    integrator_window_rad: float = 0.04
    shape: Callable[[], Callable[[FloatArray], FloatArray]] | None = None


VARIANTS: tuple[Variant, ...] = (
    Variant("model", "the model as it is"),
    Variant("noiseless", "no sensor noise (the corners alone)", config={"sensor_noise": False}),
    Variant("flow-limit-3", "valve flow saturation at 3 in/s (cylinder 2 peaks at 3.7 in/s at 5 in/s)", config={"max_cylinder_speed_in_per_s": (3.0, 3.0)}),
    Variant(
        "accel-limit",
        "corner acceleration limited: set-points smoothed over 0.23 s at 5 in/s (one f1 period), 0.18 s at 4",
        blend_s_at_5=0.23,
        blend_scales_with_speed=True,
    ),
    Variant(
        "accel-limit-noiseless",
        "as accel-limit, no sensor noise (the smoothed corners alone)",
        config={"sensor_noise": False},
        blend_s_at_5=0.23,
        blend_scales_with_speed=True,
    ),
    Variant("fixed-blend", "corners blended over a fixed 0.23 s at both speeds", blend_s_at_5=0.23),
    Variant("no-integrator", "PI without its integrator (P only)", integrator_window_rad=0.0),
    Variant("deadband-0.05", "valve deadband ±0.05 V (11 % of the lap's peak command)", shape=lambda: deadband(0.05)),
    Variant("stiction-0.05", "stick-slip: breakaway at 0.05 V, sticks again below 0.025 V", shape=lambda: breakaway(0.05)),
)


def _velocity_costs(variant: Variant, speed: float, payload: bool, seed: int) -> FloatArray:
    cfg = PlantConfig(seed=seed, payload_attached=payload, **variant.config)
    blend = variant.blend_s_at_5 * (speed / 5.0 if variant.blend_scales_with_speed else 1.0)
    run = closed_loop(
        payload=payload,
        seed=seed,
        speed_in_s=speed,
        config=cfg,
        blend_s=blend,
        integrator_window_rad=variant.integrator_window_rad,
        shape_volts=variant.shape() if variant.shape is not None else None,
    )
    return np.asarray(rms_costs(run.defl_read, 1.0 / FS).velocity_rms, dtype=float)


def corner_ring_energy(speed_in_s: float, payload: bool = False, window_s: float = 1.0) -> float:
    """Deflection-velocity energy (in²/s, both links' cameras, §4.2.1 slope) in the
    ``window_s`` after one right-angle corner, noiseless plant at 20 bits.

    The tip rests 0.5 s at the loop's apex (way-point 1), runs 5 in along the
    top row to way-point 2, turns down and runs on 5 in towards way-point 3:
    the loop's first corner, the trajectory from rest as in a lap.
    In a linear plant the energy is ∝ speed² (the velocity step is √2 v)."""
    x0, y0 = -26.383, 236.004  # way-point 1 of protocol/trajectories/inspection_loop.json
    d1 = np.array([-4.924, -0.868])  # towards way-point 2, 5 in
    d2 = np.array([0.869, -4.924])  # towards way-point 3, 5 in
    u1, u2 = d1 / np.linalg.norm(d1), d2 / np.linalg.norm(d2)
    n_rest, n_seg = int(0.5 * FS), int(round(5.0 / speed_in_s * FS))
    n_after = n_seg + int(window_s * FS) + 1
    s1 = np.minimum(np.arange(n_rest + n_seg + n_after) - n_rest, n_seg).clip(0) * speed_in_s / FS
    s2 = (np.arange(n_rest + n_seg + n_after) - n_rest - n_seg).clip(0, n_seg) * speed_in_s / FS
    xs, ys = x0 + s1 * u1[0] + s2 * u2[0], y0 + s1 * u1[1] + s2 * u2[1]
    th1, th2 = kin.inverse(xs, ys)
    ref = np.stack([th1, th2], axis=1)
    cfg = PlantConfig(payload_attached=payload, sensor_noise=False, adc_bits=20, home_theta_rad=(float(th1[0]), float(th2[0])))
    arm = RalfArm(cfg)
    integ = np.zeros(2)
    read = np.empty((ref.shape[0], 2))
    for k in range(ref.shape[0]):
        v = arm.sample().values_in
        err = ref[k] - np.array([kin.CYLINDER1.angle(v[0]), kin.CYLINDER2.angle(v[1])])
        integ = np.where(np.abs(err) < INTEGRATOR_WINDOW_RAD, integ * (1 - 1e-4) + err / FS, integ)
        arm.set_valve_voltages(KP * err + KI * integ)
        read[k] = v[2:]
        arm.advance(1.0 / FS)
    vel = deflection_velocity(read).values
    k0 = n_rest + n_seg
    seg = vel[k0 : k0 + int(window_s * FS)]
    return float(np.sum(seg**2) / FS)


def joint_acceleration_demand(speed_in_s: float, payload: bool = False) -> list[float]:
    """Largest |θ''| (rad/s², joint 1, joint 2) over a noiseless lap under the PI: what the
    corners ask of the cylinders (to compare with what 1000 psi can give)."""
    run = closed_loop(payload=payload, speed_in_s=speed_in_s, config=PlantConfig(payload_attached=payload, sensor_noise=False))
    acc = np.gradient(np.gradient(run.theta, 1.0 / FS, axis=0), 1.0 / FS, axis=0)
    return [round(float(x), 3) for x in np.abs(acc).max(axis=0)]


PSI_PA = 6894.757
SUPPLY_PSI = 1000.0
"""Thesis §3.1: the cylinders run at 1000 psi."""
PISTON_IN2 = 2.0
"""The piston area the model's oil column k_c1 assumes (docs/plant-model.md, parameters); cylinder 2 taken alike."""


def pressure_limited_acceleration(payload: bool = False, speed_in_s: float = 5.0) -> list[float]:
    """Smallest joint acceleration (rad/s², joint 1, joint 2) that the full supply pressure on a
    piston can give beyond gravity, over the lap's configurations: ``(P_s A lever − |gravity torque|)
    / rigid inertia`` about each joint (joint 1 carries the whole arm, joint 2 link 2 and the tip;
    the coupling torques of the other joint's motion left out, an estimate)."""
    from plant_emulator.model.modes import L1_M, consts

    k = consts(PlantConfig().structure, payload)
    tr = kin.sample_trajectory(dt_s=1.0 / FS, speed_in_s=speed_in_s)
    t1, t2 = tr.theta1_rad, tr.theta2_rad
    force_n = SUPPLY_PSI * PSI_PA * PISTON_IN2 * (0.0254**2)
    lever1 = np.asarray(kin.CYLINDER1.lever_in_per_rad(t1)) * 0.0254
    lever2 = np.asarray(kin.CYLINDER2.lever_in_per_rad(t2)) * 0.0254
    inertia1 = k.I1 + k.Mt * L1_M**2 + k.Ia + 2.0 * L1_M * k.S * np.cos(t2)
    gravity1 = k.g * np.abs(k.A1 * np.cos(t1) + k.S * np.cos(t1 + t2))
    gravity2 = k.g * np.abs(k.S * np.cos(t1 + t2))
    a1 = (force_n * lever1 - gravity1) / inertia1
    a2 = (force_n * lever2 - gravity2) / k.Ia
    return [round(float(a1.min()), 2), round(float(a2.min()), 2)]


def linear_corner_ratio() -> float:
    """4 in/s over 5 in/s RMS for corner-driven vibration of a linear plant: (4/5) sqrt(T5 / T4)."""
    t5 = kin.sample_trajectory(dt_s=1.0 / FS, speed_in_s=5.0).t_s[-1]
    t4 = kin.sample_trajectory(dt_s=1.0 / FS, speed_in_s=4.0).t_s[-1]
    return float(0.8 * math.sqrt(t5 / t4))


def probe(variant: Variant, seed: int = 0) -> dict[str, Any]:
    """The four groups' RMS deflection velocity (link 1, link 2) under ``variant``."""
    got = {(s, p): _velocity_costs(variant, s, p, seed) for s in SPEEDS for p in PAYLOADS}
    groups = {}
    for (s, p), v in got.items():
        thesis = np.array(THESIS_UNFILTERED[(s, p)][:2])
        groups[f"{s:g}in_s_{'payload' if p else 'nopayload'}"] = {
            "velocity_in_s": [round(float(x), 4) for x in v],
            "ratio_to_thesis": [round(float(x), 3) for x in v / thesis],
        }
    ratio = {f"{'payload' if p else 'nopayload'}": [round(float(x), 3) for x in got[(4.0, p)] / got[(5.0, p)]] for p in PAYLOADS}
    return {"what": variant.what, "groups": groups, "ratio_4_over_5": ratio}


THESIS_RATIO_4_OVER_5 = {
    ("payload" if p else "nopayload"): [round(THESIS_UNFILTERED[(4.0, p)][i] / THESIS_UNFILTERED[(5.0, p)][i], 3) for i in (0, 1)] for p in PAYLOADS
}


def run_probe(only: list[str] | None = None, seed: int = 0, say: Callable[[str], None] = print) -> dict[str, Any]:
    """The reference ratios, the acceleration figures and every variant in ``only``
    (default: all), each variant's 4/5 ratio said as soon as it is measured."""
    unknown = sorted(set(only or ()) - {v.name for v in VARIANTS})
    if unknown:
        raise ValueError(f"unknown variant(s) {', '.join(unknown)}; known: {', '.join(v.name for v in VARIANTS)}")
    chosen = [v for v in VARIANTS if only is None or v.name in only]
    out: dict[str, Any] = {
        "linear_corner_ratio": round(linear_corner_ratio(), 3),
        "thesis_ratio_4_over_5": THESIS_RATIO_4_OVER_5,
        "pressure_limited_acceleration_rad_s2": {f"{'payload' if p else 'nopayload'}": pressure_limited_acceleration(p) for p in PAYLOADS},
        "peak_joint_acceleration_rad_s2": {f"{s:g}in_s_{'payload' if p else 'nopayload'}": joint_acceleration_demand(s, p) for s in SPEEDS for p in PAYLOADS},
        "variants": {},
    }
    for v in chosen:
        out["variants"][v.name] = probe(v, seed)
        say(f"{v.name} {json.dumps(out['variants'][v.name]['ratio_4_over_5'])}")
    return out
