"""RALF's kinematics for the plant: the shared contract plus what the model
needs on top of it.

Everything geometric comes from :mod:`protocol.geometry` (thesis Appendix A
and the cylinder pin triangles) and is re-exported here, so the plant and the
controller can never disagree about a joint angle.  This module adds:

* the joint state from the cylinder state (angle, rate, and the derivative
  of the lever arm that the joint acceleration needs);
* the extension limits that realise the joint limits as hard stops;
* the inspection loop sampled in time (tip path at a given speed, with its
  pauses), used to calibrate and test the modal map and as the default home;
* the home configuration: the loop's first way-point.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

import protocol
from protocol.geometry import (
    A1_IN,
    A2_IN,
    B1_IN,
    B2_IN,
    CYLINDER1,
    CYLINDER2,
    CYLINDERS,
    DELTA_RAD,
    INCH,
    PAYLOAD_LB,
    POUND,
    THETA1_LIMITS_RAD,
    THETA2_LIMITS_RAD,
    FloatArray,
    PinTriangle,
    UnreachableError,
    elbow_position,
    forward,
    inverse,
    jacobian_determinant,
    phi_to_theta,
    theta_to_phi,
    within_limits,
    workspace_boundary,
)

__all__ = [
    "A1_IN",
    "A2_IN",
    "B1_IN",
    "B2_IN",
    "CYLINDER1",
    "CYLINDER2",
    "CYLINDERS",
    "DELTA_RAD",
    "INCH",
    "JOINT_LIMITS_RAD",
    "PAYLOAD_LB",
    "POUND",
    "THETA1_LIMITS_RAD",
    "THETA2_LIMITS_RAD",
    "FloatArray",
    "PinTriangle",
    "TrajectorySamples",
    "UnreachableError",
    "elbow_position",
    "extension_limits_in",
    "forward",
    "home_theta",
    "INSPECTION_LOOP_START_IN",
    "inverse",
    "jacobian_determinant",
    "lever_slope_in_per_rad2",
    "load_waypoints",
    "phi_to_theta",
    "sample_trajectory",
    "theta_to_phi",
    "within_limits",
    "workspace_boundary",
    "workspace_grid",
]

JOINT_LIMITS_RAD: Final[tuple[tuple[float, float], tuple[float, float]]] = (THETA1_LIMITS_RAD, THETA2_LIMITS_RAD)

TRAJECTORY_DIR: Final[Path] = Path(protocol.__file__).resolve().parent / "trajectories"


def extension_limits_in(joint: int) -> tuple[float, float]:
    """Cylinder extensions (in) at the two joint limits of ``joint`` (0 or 1).

    The pin triangles are monotonic over the joint ranges, so the joint
    limits are exactly these extension limits: the hard stops."""
    cyl = CYLINDERS[joint]
    lo, hi = JOINT_LIMITS_RAD[joint]
    return float(cyl.extension(lo)), float(cyl.extension(hi))


def lever_slope_in_per_rad2(cyl: PinTriangle, theta: float | FloatArray) -> float | FloatArray:
    """d(lever)/d(theta) of a pin triangle (in/rad^2).

    With ``L`` the cylinder length and ``lever = dL/dtheta = p q sin(g) / L``:
    ``d lever / d theta = (p q cos(g) - lever^2) / L``."""
    gamma = np.asarray(theta) + cyl.offset_rad
    length = np.asarray(cyl.length(theta))
    lever = np.asarray(cyl.lever_in_per_rad(theta))
    out = (cyl.p_in * cyl.q_in * np.cos(gamma) - lever**2) / length
    return float(out) if np.ndim(out) == 0 else out


def load_waypoints(name: str = "inspection_loop") -> dict:
    """A way-point file from ``protocol/trajectories`` (or a path)."""
    path = Path(name)
    if not path.suffix:
        path = TRAJECTORY_DIR / f"{name}.json"
    with path.open(encoding="utf-8") as fh:
        data: dict = json.load(fh)
    return data


@dataclass(frozen=True)
class TrajectorySamples:
    """A way-point path sampled uniformly in time (the tip moving at constant
    speed along straight segments, resting for each way-point's pause)."""

    t_s: FloatArray
    x_in: FloatArray
    y_in: FloatArray
    theta1_rad: FloatArray
    theta2_rad: FloatArray


def sample_trajectory(
    name: str = "inspection_loop",
    dt_s: float = 0.005,
    speed_in_s: float | None = None,
    include_pauses: bool = True,
) -> TrajectorySamples:
    """One pass of a way-point loop, sampled every ``dt_s`` (default 200 Hz).

    This is the plant's own reference sampler (for calibration, tests and the
    docs' figure); the controller has its own trajectory generator."""
    data = load_waypoints(name)
    speed = float(speed_in_s if speed_in_s is not None else data.get("speed_in_per_s", 5.0))
    if speed <= 0 or dt_s <= 0:
        raise ValueError("speed and dt must be positive")
    wps = data["waypoints"]
    pts = np.array([[w["x_in"], w["y_in"]] for w in wps], dtype=float)
    pauses = [float(w.get("pause_s", 0.0)) for w in wps]
    if data.get("closed", False) and np.hypot(*(pts[-1] - pts[0])) > 1e-9:
        pts = np.vstack([pts, pts[:1]])
        pauses.append(0.0)
    # breakpoints of a piecewise-linear path in time
    times = [0.0]
    knots = [pts[0]]
    for i in range(len(pts) - 1):
        if include_pauses and pauses[i] > 0:
            times.append(times[-1] + pauses[i])
            knots.append(pts[i])
        seg = float(np.hypot(*(pts[i + 1] - pts[i])))
        times.append(times[-1] + seg / speed)
        knots.append(pts[i + 1])
    tk = np.array(times)
    kk = np.array(knots)
    t = np.arange(0.0, tk[-1], dt_s)
    x = np.interp(t, tk, kk[:, 0])
    y = np.interp(t, tk, kk[:, 1])
    th1, th2 = inverse(x, y)
    return TrajectorySamples(t_s=t, x_in=x, y_in=y, theta1_rad=np.asarray(th1), theta2_rad=np.asarray(th2))


INSPECTION_LOOP_START_IN: Final[tuple[float, float]] = (-19.437, 196.612)
"""The inspection loop's first way-point, used when the way-point file is
not installed (``protocol/trajectories`` is not package data)."""


def home_theta(name: str = "inspection_loop") -> tuple[float, float]:
    """Joint angles (rad) at the first way-point of a loop: the plant's home."""
    try:
        w = load_waypoints(name)["waypoints"][0]
        x, y = w["x_in"], w["y_in"]
    except FileNotFoundError:
        if name != "inspection_loop":
            raise
        x, y = INSPECTION_LOOP_START_IN
    t1, t2 = inverse(x, y)
    return float(t1), float(t2)


def workspace_grid(n1: int = 41, n2: int = 111, margin_rad: float = 0.0) -> tuple[FloatArray, FloatArray]:
    """A uniform (theta1, theta2) grid over the joint limits, flattened."""
    (a, b), (c, d) = JOINT_LIMITS_RAD
    g1, g2 = np.meshgrid(np.linspace(a + margin_rad, b - margin_rad, n1), np.linspace(c + margin_rad, d - margin_rad, n2))
    return g1.ravel(), g2.ravel()


def _check() -> None:  # pragma: no cover - sanity at import is cheap
    for j in (0, 1):
        lo, hi = extension_limits_in(j)
        if not (0.0 <= lo < hi <= CYLINDERS[j].stroke_in):
            raise RuntimeError(f"joint {j + 1} limits fall outside the cylinder stroke")
    assert math.isfinite(DELTA_RAD)


_check()

FloatArrayLike = npt.ArrayLike
