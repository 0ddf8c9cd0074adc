"""RALF's hydraulic joints: valve voltage -> cylinder velocity -> extension.

Thesis §3.1: cylinders at 1000 psi, the valve voltage commands the cylinder
velocity, and a voltage step reaches steady velocity in under 20 ms.  The
hydraulics overpower the light structure, so each joint is a velocity
source: the flexible links do not load it (their reaction is not fed back).

Per cylinder ``i``::

    u_i   = clip(K_v,i * V_i, -v_max,i, +v_max,i)     flow saturation
    tau v_i' = u_i - v_i                               valve/flow first-order lag
    e_i'  = v_i                                        extension (in)

integrated *exactly* over a step of length ``h`` for a constant command
(``v(h) = u + (v0 - u) a``, ``e(h) = e0 + u h + (v0 - u) tau (1 - a)``,
``a = exp(-h / tau)``), so the step size does not change the answer.

Hard stops: the joint limits (theta1 60-100 deg, theta2 10-120 deg) are
extension limits of the pin triangles.  A cylinder that reaches one is
clamped to it and its velocity zeroed; pushing further into the stop keeps
it there (pressure builds, no flow).  Each arrival at a stop is an event.
"""

from __future__ import annotations

from dataclasses import dataclass

from plant_emulator.model.kinematics import CYLINDERS, extension_limits_in

__all__ = ["CylinderAxis", "HardStop"]


@dataclass(frozen=True)
class HardStop:
    """One arrival of a joint at a limit."""

    time_s: float
    joint: int
    """0 = joint 1 (theta1), 1 = joint 2 (theta2)."""
    side: int
    """-1 = lower limit, +1 = upper limit."""
    speed_in_s: float
    """Cylinder speed just before the stop."""


class CylinderAxis:
    """One valve + cylinder: its parameters and state (extension in in, lagged
    velocity in in/s, which stop it rests on). The step itself is
    :func:`plant_emulator.model.period_kernel.cylinder_step`."""

    def __init__(
        self,
        joint: int,
        gain_in_s_per_v: float,
        time_constant_s: float,
        max_speed_in_s: float,
        extension_in: float,
    ) -> None:
        if gain_in_s_per_v <= 0 or time_constant_s <= 0 or max_speed_in_s <= 0:
            raise ValueError("valve gain, time constant and speed limit must be positive")
        self.joint = joint
        self.cylinder = CYLINDERS[joint]
        self.gain = float(gain_in_s_per_v)
        self.tau = float(time_constant_s)
        self.vmax = float(max_speed_in_s)
        self.ext_lo, self.ext_hi = extension_limits_in(joint)
        self.extension_in = min(max(float(extension_in), self.ext_lo), self.ext_hi)
        self.velocity_in_s = 0.0
        self.stop_side = self._side(self.extension_in)

    def _side(self, ext: float) -> int:
        if ext <= self.ext_lo:
            return -1
        if ext >= self.ext_hi:
            return 1
        return 0
