"""The integrated plant: hydraulics, flexible links, sensors, on one clock.

:class:`RalfArm` is pure and deterministic: no I/O, no wall clock, no global
state.  The same seed and the same sequence of calls give bit-identical
readings and ground truth.

Time.  The state lives on a fixed grid of internal steps (default 1 ms).
:meth:`RalfArm.advance` takes any ``dt >= 0``: it converts ``dt`` to integer
nanoseconds, adds it to the remainder carried from earlier calls and runs
as many whole steps as that covers, so ``advance(a); advance(b)`` runs
exactly the same steps as ``advance(a + b)`` (real time: the wall-clock
interval between SYNCs; lockstep: one sample period, 5 internal steps).
Readings and truth describe the state at the latest grid point (at most one
internal step old).

One internal step of length ``h``, with the valve voltages held:

1. each cylinder: exact solution of the lag with flow saturation; hard stops
   clamp the extension, zero the velocity and are counted
   (:mod:`.hydraulics`);
2. joint angles from the extensions (law of cosines), joint rates from the
   lever arms; the joint acceleration over the step is
   ``(theta'(t+h) - theta'(t)) / h`` (so a hard stop delivers its velocity
   change to the links as one impulse);
3. the flexible links (:mod:`.modes`) with ``M, K, E, G`` frozen at the
   step's mid configuration: projected onto the mass-normalised modes and
   advanced with the exact solution of each damped mode under the constant
   load ``G - E theta''``, then mapped back to the physical coordinates;
4. the anti-alias filters of the deflection channels (exact ZOH
   discretisation) with the deflection sensor noise at their input.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from plant_emulator.model import kinematics as kin
from plant_emulator.model import period_kernel as pk
from plant_emulator.model.arm_state import ArmState
from plant_emulator.model.hydraulics import CylinderAxis, HardStop
from plant_emulator.model.modes import (
    DEFAULT_STRUCTURE,
    L1_M,
    L2_M,
    Structure,
    consts,
    link_arguments,
    modal_arguments,
    natural_frequencies,
    static_deflection_in,
)
from plant_emulator.sensors import AntiAliasFilter, NoiseSources, SensorReading, analog_noise_std, channel_lsb_in, read_codes, read_inputs
from protocol.can_map import FULL_SCALE_V, ConverterScale

__all__ = ["GroundTruth", "HardStop", "PlantConfig", "RalfArm"]

NS_PER_S = 1_000_000_000
MAX_EVENTS = 256
"""Hard-stop events kept in the truth (the counters never forget)."""


@functools.lru_cache(maxsize=16)
def default_deflection_zero(structure: Structure, payload: bool, bending_only: bool = True) -> tuple[float, float]:
    """Where the deflection sensors read zero unless configured: the middle
    of the static deflection's range (in) over one lap of the inspection
    loop, so the loop's static sag is centred in the sensors' +-0.575/0.555
    in ranges (each camera aimed at its diode accordingly)."""
    try:
        tr = kin.sample_trajectory(dt_s=0.05)
    except FileNotFoundError:  # way-points not installed: zero at home instead
        w = static_deflection_in(*kin.home_theta(), payload, structure, bending_only)
        return float(w[0]), float(w[1])
    w = static_deflection_in(tr.theta1_rad, tr.theta2_rad, payload, structure, bending_only)
    mid = 0.5 * (w.min(axis=0) + w.max(axis=0))
    return float(mid[0]), float(mid[1])


class PlantConfig(BaseModel):
    """Everything that makes one plant differ from another (all defaults are
    the thesis's rig as calibrated in docs/plant-model.md)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    seed: int = Field(0, ge=0, description="Seed of the sensor-noise generators")
    payload_attached: bool = Field(False, description="Start with the 15.65 lb payload at the tip")
    valve_time_constant_s: float = Field(0.01, gt=0, le=0.05, description="Valve command to cylinder velocity lag (thesis: steady within 20 ms)")
    valve_gain_in_per_s_per_v: tuple[float, float] = Field(
        (15.0, 7.0), description="Cylinder velocity per valve volt, cylinders 1 and 2 (sets the PI loop crossover)"
    )
    max_cylinder_speed_in_per_s: tuple[float, float] = Field((6.0, 6.0), description="Flow saturation: the fastest each cylinder moves")
    internal_step_s: float = Field(0.001, gt=0, le=0.005, description="Fixed internal integration step")
    adc_bits: int = Field(12, ge=8, le=24, description="A/D resolution (thesis: 12; future work: 16, 20)")
    home_theta_rad: tuple[float, float] | None = Field(None, description="Start configuration (default: the inspection loop's first way-point)")
    antialias_cutoff_hz: float = Field(40.0, gt=0, lt=100, description="Deflection anti-alias filter (2nd-order Butterworth) cutoff")
    extension_noise_std_in: tuple[float, float] = Field((5.4e-3, 4.6e-3), description="Extension noise std at 12 bits (thesis)")
    deflection_noise_std_in: tuple[float, float] = Field((2.1e-3, 3.8e-4), description="Deflection background noise std at 12 bits (thesis)")
    noise_reference_bits: int = Field(12, ge=8, le=24, description="Resolution at which the noise stds above were measured")
    sensor_noise: bool = Field(True, description="False: noiseless sensors (quantization stays)")
    deflection_zero_in: tuple[float, float] | None = Field(
        None, description="Deflection read as zero by the sensors (default: the middle of the static deflection range over the inspection loop)"
    )
    structure: Structure = Field(DEFAULT_STRUCTURE, description="The flexible structure's physical parameters")
    camera_on_link: bool = Field(
        True,
        description="Each deflection camera sits on its link's root (thesis §3.1.1: 'a camera at its base'), so it sees the link's bending, "
        "not the link turning on its actuator's compliance; False: the whole tip deflection",
    )

    @field_validator("valve_gain_in_per_s_per_v", "max_cylinder_speed_in_per_s")
    @classmethod
    def _positive(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not all(math.isfinite(x) and x > 0 for x in v):
            raise ValueError("must be two positive numbers")
        return v

    @field_validator("extension_noise_std_in", "deflection_noise_std_in")
    @classmethod
    def _non_negative(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not all(math.isfinite(x) and x >= 0 for x in v):
            raise ValueError("noise stds must be non-negative")
        return v

    @model_validator(mode="after")
    def _home_inside(self) -> PlantConfig:
        if self.home_theta_rad is not None and not bool(kin.within_limits(*self.home_theta_rad)):
            raise ValueError("home configuration outside the joint limits")
        if self.antialias_cutoff_hz >= 0.5 / self.internal_step_s:
            raise ValueError("anti-alias cutoff must be below the internal step's Nyquist frequency")
        return self


@dataclass(frozen=True)
class GroundTruth:
    """The plant's true state at ``time_s`` (test port only; never the controller's)."""

    time_s: float
    theta_rad: tuple[float, float]
    phi_rad: tuple[float, float]
    """Controlled joint variables, ``phi1 = theta1 - delta``, ``phi2 = theta2 + delta``."""
    theta_dot_rad_s: tuple[float, float]
    extensions_in: tuple[float, float]
    cylinder_velocities_in_s: tuple[float, float]
    valve_volts: tuple[float, float]
    deflections_in: tuple[float, float]
    """True tip deflections of links 1 and 2 (perpendicular to each link)."""
    deflection_rates_in_s: tuple[float, float]
    static_deflections_in: tuple[float, float]
    """Where the deflections would settle at this configuration at rest."""
    sensed_deflections_in: tuple[float, float]
    """What the deflection channels carry now: filtered, noisy, relative to the sensor zero."""
    camera_deflections_in: tuple[float, float]
    """What the cameras see (before filter, noise and zero): the links' bending
    (``deflections_in`` times the bending fractions; equal to it with ``camera_on_link`` off)."""
    modal_frequencies_hz: tuple[float, ...]
    damping_ratios: tuple[float, ...]
    tip_in: tuple[float, float]
    """True tip position, deflections included."""
    rigid_tip_in: tuple[float, float]
    """Tip position of the rigid arm at the joint angles (forward kinematics)."""
    payload_attached: bool
    at_stop: tuple[int, int]
    """Per joint: -1 resting on the lower stop, +1 on the upper, 0 free."""
    hard_stop_counts: tuple[int, int]
    hard_stop_events: tuple[HardStop, ...] = field(default_factory=tuple)
    """The most recent arrivals at a stop (up to 256)."""
    adc_bits: int = 12

    @property
    def hard_stop_count(self) -> int:
        return sum(self.hard_stop_counts)

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON-able data."""
        d = asdict(self)
        d["hard_stop_events"] = [asdict(e) for e in self.hard_stop_events]
        d["hard_stop_count"] = self.hard_stop_count
        return d


_JOINT: tuple[tuple[float, float, float, float, float, float], ...] = tuple(
    (cyl.retracted_length_in, cyl.p_in**2 + cyl.q_in**2, 2.0 * cyl.p_in * cyl.q_in, cyl.offset_rad, cyl.p_in * cyl.q_in, 2.0 * (cyl.p_in * cyl.q_in))
    for cyl in kin.CYLINDERS
)
"""Per joint, the pin triangle's constant sub-expressions as
``period_kernel.joint_angle_and_rate`` evaluates them (the same floats, each
left-to-right product and sum kept): retracted length, p^2 + q^2, 2 p q, offset, p q, 2 (p q)."""


def _hydraulic_parameters(cfg: PlantConfig, h: float, axes: tuple[CylinderAxis, ...]) -> npt.NDArray[np.float64]:
    """The period kernel's ``hp`` (``period_kernel.HP_*``): step, valve lag, cylinders, pin triangles, switches."""
    a0, a1 = axes
    if a0.tau != a1.tau:  # pragma: no cover - both come from one setting
        raise ValueError("the cylinders share one valve time constant")
    hp = np.zeros(pk.HP_SIZE)
    hp[pk.HP_STEP], hp[pk.HP_DECAY], hp[pk.HP_TAU] = h, math.exp(-h / a0.tau), a0.tau
    for j, ax in enumerate(axes):
        k = pk.HP_CYLINDER + 4 * j
        hp[k + pk.CYL_GAIN], hp[k + pk.CYL_VMAX], hp[k + pk.CYL_LO], hp[k + pk.CYL_HI] = ax.gain, ax.vmax, ax.ext_lo, ax.ext_hi
        hp[pk.HP_JOINT + 6 * j : pk.HP_JOINT + 6 * j + 6] = _JOINT[j]
    hp[pk.HP_CAMERA_ON_LINK], hp[pk.HP_SENSOR_NOISE] = float(cfg.camera_on_link), float(cfg.sensor_noise)
    return hp


def _sensor_parameters(zero: tuple[float, ...], noise_in: tuple[float, ...], aa: AntiAliasFilter) -> npt.NDArray[np.float64]:
    """The period kernel's ``sp`` (``period_kernel.SP_*``): link lengths, sensor zeros and noise, the filter."""
    sp = np.zeros(pk.SP_SIZE)
    sp[pk.SP_LINK_LENGTH : pk.SP_LINK_LENGTH + 2] = L1_M, L2_M
    sp[pk.SP_INCH] = kin.INCH
    sp[pk.SP_ZERO : pk.SP_ZERO + 2] = zero
    sp[pk.SP_NOISE_STD : pk.SP_NOISE_STD + 2] = noise_in
    sp[pk.SP_FILTER : pk.SP_FILTER + 6] = aa._c
    return sp


def _deflections(beta: tuple[float, float]) -> tuple[float, float]:
    """Tip deflections (in) for link rotations ``beta`` (rad), or their rates for rates."""
    return L1_M * beta[0] / kin.INCH, L2_M * beta[1] / kin.INCH


def _seen(fractions: tuple[float, float], beta: tuple[float, float]) -> tuple[float, float]:
    """The deflections the cameras see (in): the links' bending."""
    return fractions[0] * L1_M * beta[0] / kin.INCH, fractions[1] * L2_M * beta[1] / kin.INCH


class RalfArm:
    """RALF with its sensors: ``set_valve_voltages`` / ``advance`` / ``sample``.

    Starts at rest at the home configuration, pre-deflected to its static
    equilibrium, valves at 0 V, so a run starts without a transient."""

    def __init__(self, cfg: PlantConfig | None = None) -> None:
        self.cfg = cfg = cfg or PlantConfig()
        self._h_ns = int(round(cfg.internal_step_s * NS_PER_S))
        if self._h_ns <= 0:
            raise ValueError("internal step too small")
        self._h = self._h_ns / NS_PER_S
        self._steps = 0
        self._pending_ns = 0
        k = (consts(cfg.structure, False), consts(cfg.structure, True))
        self._link_args = (link_arguments(k[0]), link_arguments(k[1]))
        """The links' constant coefficients arguments, payload out / in."""
        self._modal_args = (modal_arguments(k[0], self._h), modal_arguments(k[1], self._h))
        """The modal step's constant arguments, payload out / in."""
        self._zetas = (k[0].z1, k[0].z2)
        self._payload = bool(cfg.payload_attached)
        th = cfg.home_theta_rad if cfg.home_theta_rad is not None else kin.home_theta()
        axes = tuple(
            CylinderAxis(
                j,
                cfg.valve_gain_in_per_s_per_v[j],
                cfg.valve_time_constant_s,
                cfg.max_cylinder_speed_in_per_s[j],
                float(kin.CYLINDERS[j].extension(th[j])),
            )
            for j in (0, 1)
        )
        self._volts = [0.0, 0.0]
        self._hp = _hydraulic_parameters(cfg, self._h, axes)
        theta = (pk.joint_angle_and_rate(self._hp, 0, axes[0].extension_in, 0.0)[0], pk.joint_angle_and_rate(self._hp, 1, axes[1].extension_in, 0.0)[0])
        self._events: deque[HardStop] = deque(maxlen=MAX_EVENTS)
        self._stop_counts = [0, 0]
        # flexible state at static equilibrium
        beta = self._static_beta(*theta)
        frac = self._fractions(*theta)
        # sensors
        self._noise = NoiseSources(cfg.seed)
        aa = AntiAliasFilter(cfg.antialias_cutoff_hz, self._h)
        self._scale = ConverterScale(cfg.adc_bits)
        ref = cfg.noise_reference_bits
        on = cfg.sensor_noise
        self._ext_noise = tuple(analog_noise_std(cfg.extension_noise_std_in[j], channel_lsb_in(j, ref)) if on else 0.0 for j in (0, 1))
        self._defl_noise_in = tuple(
            aa.input_std_for_output_std(analog_noise_std(cfg.deflection_noise_std_in[j], channel_lsb_in(2 + j, ref))) if on else 0.0 for j in (0, 1)
        )
        w = _seen(frac, beta)
        self._zero = (
            tuple(cfg.deflection_zero_in) if cfg.deflection_zero_in is not None else default_deflection_zero(cfg.structure, self._payload, cfg.camera_on_link)
        )
        aa.reset((w[0] - self._zero[0], w[1] - self._zero[1]))
        # the compiled period (period_kernel): its constant arguments and state vector
        pk.warm_up()
        self._advance_steps = pk.advance_steps
        self._sp = _sensor_parameters(self._zero, self._defl_noise_in, aa)
        self._ma = (np.array([*self._modal_args[0], 0.0, 0.0, L2_M]), np.array([*self._modal_args[1], 0.0, 0.0, L2_M]))
        """:attr:`_modal_args` as the kernel's arrays, then the tip forces (N) and link 2's length (``period_kernel.MA_FORCE1``)."""
        self._st = np.zeros(pk.STATE_SIZE)
        self._stv = memoryview(self._st)  # type: ignore[arg-type]  # numpy arrays are buffers; its stubs do not say so
        """``_st`` read element by element as Python floats (``sample``'s four reads per SYNC)."""
        at_rest = (0.0, 0.0)
        state = ArmState(
            extensions_in=(axes[0].extension_in, axes[1].extension_in),
            velocities_in_s=(axes[0].velocity_in_s, axes[1].velocity_in_s),
            stop_sides=(axes[0].stop_side, axes[1].stop_side),
            theta_rad=theta,
            theta_dot_rad_s=at_rest,
            beta_rad=beta,
            beta_dot_rad_s=at_rest,
            fractions=frac,
            antialias=((aa.state[0][0], aa.state[0][1]), (aa.state[1][0], aa.state[1][1])),
        )
        state.write(self._st)
        self._no_noise = np.zeros(0)

    # -- public API ---------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time (s): the grid time plus the carried remainder."""
        return (self._steps * self._h_ns + self._pending_ns) / NS_PER_S

    @property
    def payload_attached(self) -> bool:
        return self._payload

    @property
    def adc_bits(self) -> int:
        return self._scale.bits

    @property
    def valve_volts(self) -> tuple[float, float]:
        """The two valve voltages the arm integrates with (V, after the D/A's clipping)."""
        return self._volts[0], self._volts[1]

    @property
    def hard_stop_count(self) -> int:
        """Arrivals at a hard stop since the start, both joints."""
        return self._stop_counts[0] + self._stop_counts[1]

    def set_valve_voltages(self, volts: npt.ArrayLike) -> None:
        """The two valve voltages (V), held until the next call. The node
        hands them already quantized by the 12-bit D/A; beyond +-10 V they
        are clipped like the D/A's output."""
        v = volts if type(volts) is np.ndarray and volts.dtype == np.float64 else np.asarray(volts, dtype=np.float64)
        if v.shape != (2,):
            raise ValueError(f"two valve voltages expected, got shape {v.shape}")
        a, b = v.tolist()
        self.set_valve_values(a, b)

    def set_valve_values(self, volts0: float, volts1: float) -> None:
        """:meth:`set_valve_voltages` given two floats (no array)."""
        if not (math.isfinite(volts0) and math.isfinite(volts1)):
            raise ValueError("valve voltages must be finite")
        lo, hi = -FULL_SCALE_V, FULL_SCALE_V  # np.clip's floats for finite values, signed zeros included
        self._volts = [hi if volts0 > hi else (lo if volts0 < lo else volts0), hi if volts1 > hi else (lo if volts1 < lo else volts1)]

    def advance(self, dt: float) -> None:
        """Integrate ``dt`` seconds (``dt >= 0``) in fixed internal steps,
        carrying the remainder to the next call."""
        if not math.isfinite(dt) or dt < 0:
            raise ValueError(f"advance needs a finite dt >= 0, got {dt!r}")
        total = self._pending_ns + int(round(dt * NS_PER_S))
        n, self._pending_ns = divmod(total, self._h_ns)
        if n:
            self._run_steps(n)

    def sample(self) -> SensorReading:
        """A/D conversion of the four inputs now (on SYNC)."""
        rng = self._noise.sample if self.cfg.sensor_noise else None
        ext, aa = self._sensed()
        return read_inputs(self.time_s, ext, aa, self._ext_noise, self._scale, rng)  # type: ignore[arg-type]

    def sample_codes(self) -> tuple[list[int], list[bool]]:
        """:meth:`sample`'s codes and saturation flags as lists (``code_list``,
        ``saturated_list``), without the reading object: what a SYNC's TPDO1
        needs. The same conversion and the same noise drawn as :meth:`sample`."""
        ext, aa = self._sensed()
        return read_codes(ext, aa, self._ext_noise, self._scale, self._noise.sample if self.cfg.sensor_noise else None)  # type: ignore[arg-type]

    def sample_volts(self) -> list[float]:
        """The four A/D inputs' voltages now, before the converter (sensor noise
        included): :meth:`sample`'s ``analog_volts``, the same deviates drawn."""
        return self.sample().analog_volts.tolist()

    @property
    def adc_scale(self) -> ConverterScale:
        """The A/D converter (its resolution follows :meth:`set_adc_bits`)."""
        return self._scale

    def _sensed(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The A/D's analog inputs from the state: the cylinder extensions and the anti-alias filters' outputs."""
        v = self._stv
        ext = (v[pk.ST_EXTENSION], v[pk.ST_CYLINDER + pk.ST_EXTENSION])
        aa = (v[pk.ST_ANTIALIAS], v[pk.ST_ANTIALIAS + 2])
        return ext, aa

    def truth(self) -> GroundTruth:
        s = ArmState.read(self._st)
        f, z, w, (t1, t2), tip, payload = self._summary(s)
        p1, p2 = t1 - kin.DELTA_RAD, t2 + kin.DELTA_RAD  # kin.theta_to_phi on floats
        t12 = t1 + t2
        xr, yr = kin.A1_IN * math.cos(t1) + kin.A2_IN * math.cos(t12), kin.A1_IN * math.sin(t1) + kin.A2_IN * math.sin(t12)  # kin.forward on floats
        return GroundTruth(
            time_s=self.time_s,
            theta_rad=(t1, t2),
            phi_rad=(float(p1), float(p2)),
            theta_dot_rad_s=s.theta_dot_rad_s,
            extensions_in=s.extensions_in,
            cylinder_velocities_in_s=s.velocities_in_s,
            valve_volts=(self._volts[0], self._volts[1]),
            deflections_in=w,
            deflection_rates_in_s=_deflections(s.beta_dot_rad_s),
            static_deflections_in=_deflections(self._static_beta(t1, t2)),
            sensed_deflections_in=(s.antialias[0][0], s.antialias[1][0]),
            camera_deflections_in=_seen(s.fractions, s.beta_rad),
            modal_frequencies_hz=f,
            damping_ratios=z,
            tip_in=tip,
            rigid_tip_in=(float(xr), float(yr)),
            payload_attached=payload,
            at_stop=s.stop_sides,
            hard_stop_counts=(self._stop_counts[0], self._stop_counts[1]),
            hard_stop_events=tuple(self._events),
            adc_bits=self._scale.bits,
        )

    def truth_summary(
        self,
    ) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, float], tuple[float, float], tuple[float, float], bool]:
        """What the plant publishes of :meth:`truth` (modal frequencies, damping
        ratios, deflections, joint angles, tip, payload), without the rest: the
        20 Hz ground truth of a run costs a third. :meth:`truth` builds on it."""
        return self._summary(ArmState.read(self._st))

    def _summary(self, s: ArmState) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, float], tuple[float, float], tuple[float, float], bool]:
        t1, t2 = s.theta_rad
        f = natural_frequencies(self._link_args[self._payload], t1, t2)
        return (f[0], f[1]), self._zetas, _deflections(s.beta_rad), (t1, t2), self._tip(s), self._payload

    def attach_payload(self, attached: bool) -> None:
        """Pick up (True) or release (False) the payload now: the mass,
        modes and static load change at once; positions and velocities of the
        links are continuous, so the arm rings about its new equilibrium."""
        self._payload = bool(attached)

    def set_tip_forces(self, force1_n: float, force2_n: float) -> None:
        """Disturbance forces (N) at the tips of link 1 (the elbow) and link 2,
        perpendicular to each link, positive towards increasing beta; held
        until the next call (0, 0: none). They load the flexible links as
        generalized forces (:func:`.period_kernel.links_step`)."""
        if not (math.isfinite(force1_n) and math.isfinite(force2_n)):
            raise ValueError("tip forces must be finite")
        for ma in self._ma:
            ma[pk.MA_FORCE1] = force1_n
            ma[pk.MA_FORCE1 + 1] = force2_n

    def set_adc_bits(self, bits: int) -> None:
        """Change the A/D resolution (12, 16, 20 ...); the analog noise stays."""
        self._scale = ConverterScale(int(bits))

    def reseed(self, seed: int) -> None:
        """Restart both noise generators from ``seed``."""
        if int(seed) < 0:
            raise ValueError("seed must be non-negative")
        self._noise.reseed(int(seed))

    def close(self) -> None:
        """Nothing to free (:class:`~plant_emulator.plant_model.PlantModel`'s end of run)."""

    # -- internals ----------------------------------------------------------------------
    def _static_beta(self, t1: float, t2: float) -> tuple[float, float]:
        co = pk.link_coefficients(t1, t2, *self._link_args[self._payload])
        K11, K12, K22, G1, G2 = co[3], co[4], co[5], co[10], co[11]
        det = K11 * K22 - K12 * K12
        return (K22 * G1 - K12 * G2) / det, (K11 * G2 - K12 * G1) / det

    def _fractions(self, t1: float, t2: float) -> tuple[float, float]:
        """What share of each tip deflection the cameras see (1, 1 with ``camera_on_link`` off)."""
        return pk.camera_fractions(self._modal_args[self._payload], kin.INCH, t1, t2) if self.cfg.camera_on_link else (1.0, 1.0)

    def _tip(self, s: ArmState) -> tuple[float, float]:
        """Tip position (in) with the flexing: link 1 turns by beta1 about
        joint 1, link 2 by kappa*beta1 + beta2 about the elbow."""
        t1, t2 = s.theta_rad
        b1, b2 = s.beta_rad
        kap = self.cfg.structure.slope_transmission
        a1 = t1 + b1
        a12 = t1 + t2 + kap * b1 + b2
        return (kin.A1_IN * math.cos(a1) + kin.A2_IN * math.cos(a12), kin.A1_IN * math.sin(a1) + kin.A2_IN * math.sin(a12))

    def _run_steps(self, n: int) -> None:
        """``n`` internal steps through :func:`.period_kernel.advance_steps`
        on the state ``_st``."""
        st = self._st
        noise = self._noise
        noisy = self.cfg.sensor_noise
        volts0, volts1 = self._volts
        ma = self._ma[self._payload]
        while n:
            block, nxt = noise.step_block() if noisy else (self._no_noise, 0)
            done, nxt, status, arr0, spd0, side0, arr1, spd1, side1 = self._advance_steps(n, volts0, volts1, st, self._hp, self._sp, ma, block, nxt)
            if noisy:
                noise.step_used(nxt)
            self._steps += done
            n -= done
            if status == pk.STATUS_STOP:
                t_end = self._steps * self._h_ns / NS_PER_S
                for j, arrived, side, speed in ((0, arr0, side0, spd0), (1, arr1, side1, spd1)):
                    if arrived:
                        self._stop_counts[j] += 1
                        self._events.append(HardStop(time_s=t_end, joint=j, side=side, speed_in_s=speed))
