"""RALF's geometry: link lengths, kinematics (thesis Appendix A) and the
cylinder pin triangles that turn cylinder extensions into joint angles.

Conventions (right-handed, x to the right, y up, angles counter-clockwise):

* ``theta1`` is the angle of the line from joint 1 to joint 2 above the
  horizontal; ``theta2`` is the elbow angle of link 2 relative to that line.
* Link 1 is an L-shaped beam (``b1`` along, ``b2`` across), so its effective
  length is ``a1 = sqrt(b1**2 + b2**2)`` and the controlled joint variables
  are ``phi1 = theta1 - delta`` and ``phi2 = theta2 + delta`` with
  ``delta = atan(b2 / b1)`` [A.7-A.9].
* The elbow-up solution (``theta2 > 0``) is the only one inside the joint
  limits.  The thesis prints [A.5] with a mirrored x axis; what must hold,
  and is tested, is ``forward(inverse(p)) == p`` over the workspace.

Pin triangles (our choice; the thesis gives none, see docs/plant-model.md):
each hydraulic cylinder spans two pins at distances ``p`` and ``q`` from the
joint axis, so by the law of cosines its length is
``L = sqrt(p**2 + q**2 - 2 p q cos(gamma))`` with ``gamma = theta + offset``.
The Temposonics sensor reads the extension ``L - L_retracted`` over a 20 in
range.  Cylinder 2 drives the elbow through the parallel bar; the bar
reproduces the elbow angle at the base, so its triangle is written in
``theta2`` directly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

INCH: Final[float] = 0.0254
"""Metres per inch."""
POUND: Final[float] = 0.45359237
"""Kilograms per pound (mass)."""

B1_IN: Final[float] = 120.0
B2_IN: Final[float] = 5.75
A1_IN: Final[float] = math.hypot(B1_IN, B2_IN)
"""Effective length of link 1, ``a1 = sqrt(b1^2 + b2^2)`` (Appendix A)."""
A2_IN: Final[float] = 120.0
DELTA_RAD: Final[float] = math.atan(B2_IN / B1_IN)
"""Offset between the thesis's theta and the controlled phi [A.9]."""

THETA1_LIMITS_RAD: Final[tuple[float, float]] = (math.radians(60.0), math.radians(100.0))
THETA2_LIMITS_RAD: Final[tuple[float, float]] = (math.radians(10.0), math.radians(120.0))

PAYLOAD_LB: Final[float] = 15.65
"""The steel plate the thesis attaches at the tip."""


@dataclass(frozen=True)
class PinTriangle:
    """The triangle formed by a cylinder and its two pins around a joint.

    ``length = sqrt(p^2 + q^2 - 2 p q cos(theta + offset))`` (law of cosines);
    ``extension = length - retracted_length`` is what the Temposonics sensor
    reads, over ``[0, stroke]`` inches.
    """

    p_in: float
    q_in: float
    offset_rad: float
    retracted_length_in: float
    stroke_in: float = 20.0

    def length(self, theta: float | FloatArray) -> float | FloatArray:
        gamma = np.asarray(theta) + self.offset_rad
        out = np.sqrt(self.p_in**2 + self.q_in**2 - 2.0 * self.p_in * self.q_in * np.cos(gamma))
        return float(out) if np.ndim(out) == 0 else out

    def extension(self, theta: float | FloatArray) -> float | FloatArray:
        """Cylinder extension (in) for a joint angle (rad)."""
        out = np.asarray(self.length(theta)) - self.retracted_length_in
        return float(out) if np.ndim(out) == 0 else out

    def angle(self, extension_in: float | FloatArray) -> float | FloatArray:
        """Joint angle (rad) from a measured extension (in), law of cosines.

        Extensions outside the triangle's reach are clipped to it, so a noisy
        reading at a hard stop gives the stop, never NaN.
        """
        length = np.asarray(extension_in) + self.retracted_length_in
        cos_gamma = (self.p_in**2 + self.q_in**2 - length**2) / (2.0 * self.p_in * self.q_in)
        out = np.arccos(np.clip(cos_gamma, -1.0, 1.0)) - self.offset_rad
        return float(out) if np.ndim(out) == 0 else out

    def lever_in_per_rad(self, theta: float | FloatArray) -> float | FloatArray:
        """d(extension)/d(theta): inches of stroke per radian at ``theta``."""
        gamma = np.asarray(theta) + self.offset_rad
        out = self.p_in * self.q_in * np.sin(gamma) / np.asarray(self.length(theta))
        return float(out) if np.ndim(out) == 0 else out


CYLINDER1: Final[PinTriangle] = PinTriangle(p_in=30.0, q_in=30.0, offset_rad=math.radians(-29.0), retracted_length_in=15.5)
"""Joint 1: 31 deg to 71 deg of pin angle over the 60-100 deg joint range:
about 18.8 in of the 20 in stroke, 27 in/rad on average."""
CYLINDER2: Final[PinTriangle] = PinTriangle(p_in=13.0, q_in=13.0, offset_rad=math.radians(10.0), retracted_length_in=4.0)
"""Joint 2 (through the parallel bar): 20 deg to 130 deg of pin angle over the
10-120 deg elbow range: about 19.1 in of stroke, 10 in/rad on average."""
CYLINDERS: Final[tuple[PinTriangle, PinTriangle]] = (CYLINDER1, CYLINDER2)


def forward(theta1: float | FloatArray, theta2: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Tip position (in) from joint angles [A.1]."""
    t1 = np.asarray(theta1, dtype=float)
    t12 = t1 + np.asarray(theta2, dtype=float)
    return A1_IN * np.cos(t1) + A2_IN * np.cos(t12), A1_IN * np.sin(t1) + A2_IN * np.sin(t12)


def elbow_position(theta1: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position (in) of joint 2 (the end of link 1)."""
    t1 = np.asarray(theta1, dtype=float)
    return A1_IN * np.cos(t1), A1_IN * np.sin(t1)


class UnreachableError(ValueError):
    """A tip position outside the annulus the two links can reach."""


def inverse(x: float | FloatArray, y: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Joint angles (rad) for a tip position (in), elbow-up [A.5, A.6].

    Raises :class:`UnreachableError` for points outside ``|a1 - a2| <= r <= a1 + a2``.
    Joint limits are not checked here: see :func:`within_limits`.
    """
    xa = np.asarray(x, dtype=float)
    ya = np.asarray(y, dtype=float)
    r2 = xa**2 + ya**2
    r = np.sqrt(r2)
    if np.any(r > A1_IN + A2_IN + 1e-9) or np.any(r < abs(A1_IN - A2_IN) - 1e-9):
        raise UnreachableError(f"tip position at radius {np.max(r):.3f} in is outside the reachable annulus")
    cos_elbow = np.clip((A1_IN**2 + A2_IN**2 - r2) / (2.0 * A1_IN * A2_IN), -1.0, 1.0)
    theta2 = np.pi - np.arccos(cos_elbow)  # [A.6]
    cos_beta = np.clip((A1_IN**2 + r2 - A2_IN**2) / (2.0 * A1_IN * np.maximum(r, 1e-12)), -1.0, 1.0)
    theta1 = np.arctan2(ya, xa) - np.arccos(cos_beta)  # [A.5], x axis not mirrored
    return theta1, theta2


def theta_to_phi(theta1: float | FloatArray, theta2: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Controlled joint variables [A.7, A.8]: ``phi1 = theta1 - delta``, ``phi2 = theta2 + delta``."""
    return np.asarray(theta1) - DELTA_RAD, np.asarray(theta2) + DELTA_RAD


def phi_to_theta(phi1: float | FloatArray, phi2: float | FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`theta_to_phi`."""
    return np.asarray(phi1) + DELTA_RAD, np.asarray(phi2) - DELTA_RAD


def within_limits(theta1: float | FloatArray, theta2: float | FloatArray, margin_rad: float = 0.0) -> npt.NDArray[np.bool_]:
    """True where both joints are inside their limits (shrunk by ``margin_rad``)."""
    t1 = np.asarray(theta1)
    t2 = np.asarray(theta2)
    return (
        (t1 >= THETA1_LIMITS_RAD[0] + margin_rad)
        & (t1 <= THETA1_LIMITS_RAD[1] - margin_rad)
        & (t2 >= THETA2_LIMITS_RAD[0] + margin_rad)
        & (t2 <= THETA2_LIMITS_RAD[1] - margin_rad)
    )


def jacobian_determinant(theta2: float | FloatArray) -> FloatArray:
    """``det J = a1 a2 sin(theta2)``: zero at the stretched-out singularity
    that bounds the top of the workspace."""
    return A1_IN * A2_IN * np.sin(np.asarray(theta2, dtype=float))


def workspace_boundary(points_per_edge: int = 100) -> tuple[FloatArray, FloatArray]:
    """Closed outline (in) of the reachable workspace within the joint limits."""
    (t1lo, t1hi), (t2lo, t2hi) = THETA1_LIMITS_RAD, THETA2_LIMITS_RAD
    n = points_per_edge
    edges = [
        (np.linspace(t1lo, t1hi, n), np.full(n, t2lo)),  # top: nearly stretched, near-singular
        (np.full(n, t1hi), np.linspace(t2lo, t2hi, n)),
        (np.linspace(t1hi, t1lo, n), np.full(n, t2hi)),
        (np.full(n, t1lo), np.linspace(t2hi, t2lo, n)),
    ]
    t1 = np.concatenate([e[0] for e in edges])
    t2 = np.concatenate([e[1] for e in edges])
    return forward(t1, t2)
