"""One control tick of the MVME CPU, pure and deterministic (thesis §4):

A/D words -> engineering values -> set-point from the trajectory -> OATF
(outer, on the set-points) -> PI -> OATF (inner, on the commands) -> D/A.

No I/O and no clocks here: the service feeds words and gets volts, so the
same law runs over CAN in three processes or directly against the plant
model in one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from controller.engineering import Measurement, measure
from controller.oatf import OatfConfig, OatfFilter, OatfSupervisor
from controller.pi import PIConfig, PIController
from controller.trajectory import SampledTrajectory
from protocol.can_map import DAC12
from protocol.messages import Interrupt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class LawConfig:
    """What the control law needs, in its own terms (the service maps its
    settings into it: :func:`controller.config.law_config`)."""

    sample_period_s: float
    oatf_mode: Literal["off", "fixed", "adaptive"] = "off"
    oatf_location: Literal["outer", "inner"] = "outer"
    oatf_frequency_hz: float = 4.4
    """The OATF's initial design (and the ``fixed`` fallback's)."""
    oatf_fallback: Literal["last", "fixed"] = "last"
    oatf: OatfConfig | None = None
    """The OATF's design rules (None: off)."""


@dataclass(frozen=True)
class TickOutput:
    """What one tick commands and what it records."""

    volts: FloatArray
    """Valve voltages after D/A quantization (what the plant receives)."""
    clipped: npt.NDArray[np.bool_]
    measurement: Measurement
    setpoint_rad: FloatArray
    shaped_setpoint_rad: FloatArray
    pi_output_v: FloatArray


class ControlLaw:
    """Trajectory, OATF and PI for the two joints."""

    def __init__(self, config: LawConfig, trajectory: SampledTrajectory) -> None:
        self.config = config
        self.trajectory = trajectory
        self.setpoints = self.trajectory.joints.phi
        self.lap_ticks = len(self.setpoints)
        self.pi = PIController(PIConfig(sample_period_s=config.sample_period_s))
        self.degraded = False
        self.oatf: OatfFilter | None = None
        self.supervisor: OatfSupervisor | None = None
        if config.oatf_mode != "off":
            if config.oatf is None:
                raise ValueError(f"OATF mode {config.oatf_mode!r} needs its design rules (LawConfig.oatf)")
            initial = self.setpoints[0] if config.oatf_location == "outer" else 0.0
            self.oatf = OatfFilter([config.oatf_frequency_hz], n_channels=2, config=config.oatf, initial=initial)
            self.supervisor = OatfSupervisor(self.oatf)

    @property
    def oatf_frequency_hz(self) -> float:
        """The OATF's current design frequency (NaN when off)."""
        if self.oatf is None or not self.oatf.stages:
            return float("nan")
        return float(self.oatf.stages[0].frequency_hz)

    def setpoint(self, tick: int) -> FloatArray:
        """phi set-points at ``tick``; the closed loop repeats lap after lap."""
        return np.asarray(self.setpoints[tick % self.lap_ticks], dtype=np.float64)

    def step(self, tick: int, words: npt.ArrayLike) -> TickOutput:
        m = measure(words)
        ref = self.setpoint(tick)
        shaped = ref
        if self.oatf is not None and self.config.oatf_location == "outer":
            shaped = self.oatf.step(ref)
        u = self.pi.update(shaped, m.phi_rad)
        if self.oatf is not None and self.config.oatf_location == "inner":
            u = np.clip(self.oatf.step(u), -DAC12.full_scale_v, DAC12.full_scale_v)
        q = DAC12.quantize(u)
        return TickOutput(
            volts=DAC12.to_volts(q.counts),
            clipped=q.saturated,
            measurement=m,
            setpoint_rad=ref,
            shaped_setpoint_rad=np.asarray(shaped, dtype=np.float64),
            pi_output_v=np.asarray(u, dtype=np.float64),
        )

    def set_degraded(self, degraded: bool) -> None:
        """While degraded the OATF stops adapting; with the ``fixed`` fallback
        it also returns to the configured design frequency."""
        if degraded and not self.degraded and self.oatf is not None and self.config.oatf_fallback == "fixed":
            self.oatf.update_modes([self.config.oatf_frequency_hz])
        self.degraded = degraded

    def apply_interrupt(self, interrupt: Interrupt) -> bool:
        """Adaptive OATF: offer the identified first mode; True if the filter changed."""
        if self.supervisor is None or self.config.oatf_mode != "adaptive" or not interrupt.poles or self.degraded:
            return False
        return self.supervisor.offer_interrupt(interrupt)

    def record_row(self, tick: int, out: TickOutput) -> dict[str, Any]:
        """One row of the run record. The arrays are read with ``tolist`` (the
        same float64 values as indexing them, as Python floats; the words as
        ints, converted to float64 by the record exactly as int64 is): one
        call per array instead of one numpy scalar per column."""
        m = out.measurement
        ref1, ref2 = out.setpoint_rad.tolist()
        sh1, sh2 = out.shaped_setpoint_rad.tolist()
        phi1, phi2 = m.phi_rad.tolist()
        th1, th2 = m.theta_rad.tolist()
        ext1, ext2 = m.extension_in.tolist()
        d1, d2 = m.deflection_in.tolist()
        w1, w2, w3, w4 = m.words.tolist()
        v1, v2, v3, v4 = m.volts.tolist()
        u1, u2 = out.volts.tolist()
        pi1, pi2 = out.pi_output_v.tolist()
        return {
            "tick": tick,
            "t_s": tick * self.config.sample_period_s,
            "phi_ref1": ref1,
            "phi_ref2": ref2,
            "phi_shaped1": sh1,
            "phi_shaped2": sh2,
            "phi1": phi1,
            "phi2": phi2,
            "theta1": th1,
            "theta2": th2,
            "ext1_in": ext1,
            "ext2_in": ext2,
            "defl1_in": d1,
            "defl2_in": d2,
            "ai1_word": w1,
            "ai2_word": w2,
            "ai3_word": w3,
            "ai4_word": w4,
            "ai1_v": v1,
            "ai2_v": v2,
            "ai3_v": v3,
            "ai4_v": v4,
            "u1_v": u1,
            "u2_v": u2,
            "pi1_v": pi1,
            "pi2_v": pi2,
            "oatf_hz": self.oatf_frequency_hz,
        }
