"""Trajectories as data: way-points (in) to tip path to joint set-points (thesis §4, Fig. 4.3).

A trajectory file (e.g. ``protocol/trajectories/inspection_loop.json``) lists
tip way-points in inches with optional pauses, a tip speed and whether the
loop is closed.  :func:`sample_trajectory` turns it into the tip path
sampled at the control rate, straight segments at constant speed, and the
joint set-points by elbow-up inverse kinematics [A.5, A.6] and
``phi = theta -/+ delta`` [A.7-A.9] (``protocol.geometry``).  Every
way-point and every sample of the path is checked against the joint limits,
because the workspace is not convex: a straight segment between two
reachable way-points can leave it.

Timing.  The tip waits ``pause_s`` at a way-point when it arrives there (at
way-point 0, that is at the start of each lap), then moves to the next at
``speed``; zero-length segments (a closed file that repeats its first point)
take no time.  A closed trajectory ends back at way-point 0; ``repeat`` laps
run back to back.  The last sample holds the final position
(``ceil(duration / Ts) + 1`` samples from ``t = 0``).

Corners.  The thesis ran sharp right-angle corners, whose velocity steps
excite the modes at the corner period (1 s at 5 in/s on 5 in teeth); that is
part of what the experiments measure, so the default keeps them sharp
(``corner_blend_s = 0``).  A positive ``corner_blend_s`` averages the tip
path over a centred window of that length (an odd number of samples): each
velocity step becomes a linear ramp over the window (bounded acceleration),
straight constant-speed stretches and pauses longer than the window are
unchanged, and the timing is not shifted.  At the blended instant a
right-angle corner is passed at ``sqrt(2) / 8 * speed * corner_blend_s``
from the corner and a reversal (the default loop has two) stops
``speed * corner_blend_s / 4`` short of its turning point.  The blended path
is re-checked against the joint limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field

from protocol import geometry
from protocol.bounded_parse import load_json
from protocol.files import MAX_BYTES, read_regular_text

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DEFAULT_TRAJECTORY_PATH",
    "JointSetpoints",
    "SampledTrajectory",
    "TipPath",
    "TrajectoryLimitError",
    "Waypoint",
    "WaypointTrajectory",
    "check_waypoints",
    "joint_setpoints",
    "load_trajectory",
    "plot_workspace",
    "sample_tip_path",
    "sample_trajectory",
    "trajectory_duration_s",
]

DEFAULT_TRAJECTORY_PATH: Path = Path(geometry.__file__).resolve().parent / "trajectories" / "inspection_loop.json"
"""The thesis's inspection loop (Fig. 4.3) shipped with ``protocol``."""

_MIN_SEGMENT_IN = 1e-9


class TrajectoryLimitError(ValueError):
    """A way-point or a sample of the path is unreachable or outside the joint limits."""


class Waypoint(BaseModel):
    """One tip way-point (in), with an optional pause on arrival (s)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    x_in: float = Field(allow_inf_nan=False)
    y_in: float = Field(allow_inf_nan=False)
    pause_s: float = Field(0.0, ge=0.0, allow_inf_nan=False)


class WaypointTrajectory(BaseModel):
    """A way-point trajectory file (see ``protocol/trajectories/*.json``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str
    description: str = ""
    units: Literal["in"] = Field("in", description="Length unit of the way-points (only inches).")
    speed_in_per_s: float = Field(gt=0.0, allow_inf_nan=False, description="Tip speed along the segments (in/s).")
    closed: bool = Field(False, description="The tip returns to the first way-point at the end of a lap.")
    waypoints: list[Waypoint] = Field(min_length=2)

    def with_speed(self, speed_in_per_s: float) -> WaypointTrajectory:
        """A copy at another tip speed (the thesis ran 4 and 5 in/s)."""
        return WaypointTrajectory.model_validate({**self.model_dump(), "speed_in_per_s": speed_in_per_s})


def load_trajectory(path: str | Path = DEFAULT_TRAJECTORY_PATH) -> WaypointTrajectory:
    """Read and validate a way-point JSON file."""
    text = read_regular_text(path)  # a FIFO or device named here must not block the start
    return WaypointTrajectory.model_validate(load_json(text, f"trajectory {path}", max_bytes=MAX_BYTES))


@dataclass(frozen=True)
class TipPath:
    """The tip path sampled at the control rate: ``x_in[k], y_in[k]`` at ``t_s[k] = k Ts``."""

    t_s: FloatArray
    x_in: FloatArray
    y_in: FloatArray
    sample_period_s: float
    speed_in_per_s: float

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1])

    def __len__(self) -> int:
        return int(self.t_s.size)


@dataclass(frozen=True)
class JointSetpoints:
    """Joint set-points along a tip path (rad): thesis angles theta and controlled phi [A.7-A.9]."""

    t_s: FloatArray
    theta1: FloatArray
    theta2: FloatArray
    phi1: FloatArray
    phi2: FloatArray

    @property
    def phi(self) -> FloatArray:
        """``(n_samples, 2)`` array of the controlled joint variables."""
        return np.column_stack([self.phi1, self.phi2])

    @property
    def theta(self) -> FloatArray:
        return np.column_stack([self.theta1, self.theta2])


@dataclass(frozen=True)
class SampledTrajectory:
    """A trajectory ready for the loop: tip path and joint set-points on the same time grid."""

    name: str
    path: TipPath
    joints: JointSetpoints


# --------------------------------------------------------------------------- timing


def _lap_points(traj: WaypointTrajectory) -> list[Waypoint]:
    pts = list(traj.waypoints)
    if traj.closed:
        first = pts[0]
        last = pts[-1]
        if math.hypot(last.x_in - first.x_in, last.y_in - first.y_in) > _MIN_SEGMENT_IN:
            pts.append(Waypoint(x_in=first.x_in, y_in=first.y_in))
    return pts


def _knots(traj: WaypointTrajectory, speed: float, repeat: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Piecewise-linear knots (t, x, y): arrival, end of pause, next arrival, ..."""
    if repeat < 1:
        raise ValueError(f"repeat must be >= 1, got {repeat}")
    lap = _lap_points(traj)
    p0, pn = lap[0], lap[-1]
    if repeat > 1 and math.hypot(pn.x_in - p0.x_in, pn.y_in - p0.y_in) > _MIN_SEGMENT_IN:
        raise ValueError("repeat > 1 needs a closed trajectory (or one that ends where it starts)")
    ts: list[float] = [0.0]
    xs: list[float] = [p0.x_in]
    ys: list[float] = [p0.y_in]
    t = 0.0
    for _ in range(repeat):
        for i, wp in enumerate(lap):
            if i > 0:
                seg = math.hypot(wp.x_in - xs[-1], wp.y_in - ys[-1])
                if seg > _MIN_SEGMENT_IN:
                    t += seg / speed
                    ts.append(t)
                    xs.append(wp.x_in)
                    ys.append(wp.y_in)
            if wp.pause_s > 0.0:
                t += wp.pause_s
                ts.append(t)
                xs.append(wp.x_in)
                ys.append(wp.y_in)
    return np.asarray(ts), np.asarray(xs), np.asarray(ys)


def trajectory_duration_s(traj: WaypointTrajectory, speed_in_per_s: float | None = None, repeat: int = 1) -> float:
    """Length of the trajectory in time (s): path length / speed plus pauses, times ``repeat``."""
    return float(_knots(traj, speed_in_per_s or traj.speed_in_per_s, repeat)[0][-1])


def sample_tip_path(
    traj: WaypointTrajectory,
    sample_period_s: float = 0.005,
    *,
    speed_in_per_s: float | None = None,
    repeat: int = 1,
    corner_blend_s: float = 0.0,
) -> TipPath:
    """The tip path at ``t_k = k Ts``; see the module docstring for timing and corner blending."""
    if not sample_period_s > 0.0:
        raise ValueError("sample_period_s must be positive")
    speed = float(speed_in_per_s) if speed_in_per_s is not None else traj.speed_in_per_s
    if not (math.isfinite(speed) and speed > 0.0):
        raise ValueError(f"speed must be positive, got {speed}")
    kt, kx, ky = _knots(traj, speed, repeat)
    n = int(math.ceil(kt[-1] / sample_period_s - 1e-9)) + 1
    t = np.arange(n) * sample_period_s
    x = np.interp(t, kt, kx)
    y = np.interp(t, kt, ky)
    if corner_blend_s > 0.0:
        half = int(round(corner_blend_s / (2.0 * sample_period_s)))
        x, y = _centred_mean(x, half), _centred_mean(y, half)
    elif corner_blend_s < 0.0:
        raise ValueError("corner_blend_s must be >= 0")
    return TipPath(t_s=np.asarray(t, dtype=np.float64), x_in=x, y_in=y, sample_period_s=float(sample_period_s), speed_in_per_s=speed)


def _centred_mean(v: FloatArray, half: int) -> FloatArray:
    """Centred moving average over ``2 half + 1`` samples, ends held (edge padding)."""
    if half <= 0:
        return v
    padded = np.pad(v, half, mode="edge")
    c = np.cumsum(np.concatenate([[0.0], padded]))
    w = 2 * half + 1
    return (c[w:] - c[:-w]) / w


# --------------------------------------------------------------------------- kinematics and limits


def _describe_limits() -> str:
    (a, b), (c, d) = geometry.THETA1_LIMITS_RAD, geometry.THETA2_LIMITS_RAD
    return f"theta1 in [{math.degrees(a):.1f}, {math.degrees(b):.1f}] deg, theta2 in [{math.degrees(c):.1f}, {math.degrees(d):.1f}] deg"


def _inverse_checked(x: FloatArray, y: FloatArray, what: str) -> tuple[FloatArray, FloatArray]:
    try:
        return geometry.inverse(x, y)
    except geometry.UnreachableError as exc:
        r = np.hypot(x, y)
        bad = np.flatnonzero((r > geometry.A1_IN + geometry.A2_IN) | (r < abs(geometry.A1_IN - geometry.A2_IN)))
        first = int(bad[0]) if bad.size else 0
        raise TrajectoryLimitError(f"{what} {first} at ({x[first]:.3f}, {y[first]:.3f}) in is unreachable: {exc}") from exc


def check_waypoints(traj: WaypointTrajectory, margin_rad: float = 0.0) -> None:
    """Raise :class:`TrajectoryLimitError` naming every way-point outside the joint limits."""
    x = np.array([w.x_in for w in traj.waypoints])
    y = np.array([w.y_in for w in traj.waypoints])
    t1, t2 = _inverse_checked(x, y, "way-point")
    ok = geometry.within_limits(t1, t2, margin_rad)
    if not np.all(ok):
        bad = [f"#{i} ({x[i]:.3f}, {y[i]:.3f}) in -> theta1 {math.degrees(t1[i]):.2f} deg, theta2 {math.degrees(t2[i]):.2f} deg" for i in np.flatnonzero(~ok)]
        raise TrajectoryLimitError(
            f"trajectory {traj.name!r}: way-points outside the joint limits ({_describe_limits()}, margin {margin_rad} rad): " + "; ".join(bad)
        )


def joint_setpoints(path: TipPath, margin_rad: float = 0.0) -> JointSetpoints:
    """Inverse kinematics of every sample [A.5-A.9]; raises :class:`TrajectoryLimitError` outside the limits."""
    t1, t2 = _inverse_checked(path.x_in, path.y_in, "path sample")
    ok = geometry.within_limits(t1, t2, margin_rad)
    if not np.all(ok):
        bad = np.flatnonzero(~ok)
        k = int(bad[0])
        raise TrajectoryLimitError(
            f"{bad.size} path samples outside the joint limits ({_describe_limits()}, margin {margin_rad} rad); "
            f"first at t = {path.t_s[k]:.3f} s, tip ({path.x_in[k]:.3f}, {path.y_in[k]:.3f}) in, "
            f"theta1 {math.degrees(t1[k]):.2f} deg, theta2 {math.degrees(t2[k]):.2f} deg"
        )
    p1, p2 = geometry.theta_to_phi(t1, t2)
    return JointSetpoints(t_s=path.t_s, theta1=t1, theta2=t2, phi1=np.asarray(p1), phi2=np.asarray(p2))


def sample_trajectory(
    traj: WaypointTrajectory,
    sample_period_s: float = 0.005,
    *,
    speed_in_per_s: float | None = None,
    repeat: int = 1,
    corner_blend_s: float = 0.0,
    margin_rad: float = 0.0,
) -> SampledTrajectory:
    """Check the way-points, sample the tip path and compute the joint set-points (all checked)."""
    check_waypoints(traj, margin_rad)
    path = sample_tip_path(traj, sample_period_s, speed_in_per_s=speed_in_per_s, repeat=repeat, corner_blend_s=corner_blend_s)
    return SampledTrajectory(name=traj.name, path=path, joints=joint_setpoints(path, margin_rad))


# --------------------------------------------------------------------------- plot


def plot_workspace(
    png_path: str | Path,
    traj: WaypointTrajectory | None = None,
    path: TipPath | None = None,
    *,
    title: str | None = None,
    zoom: bool = False,
) -> Path:
    """Draw the workspace outline within the joint limits, and optionally the way-points and
    the sampled path, to a PNG (Agg, no display needed).  ``zoom`` frames the trajectory."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(7.0, 6.0), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    bx, by = geometry.workspace_boundary()
    ax.plot(np.append(bx, bx[0]), np.append(by, by[0]), color="0.3", lw=1.2, label="workspace (joint limits)")
    if path is not None:
        ax.plot(path.x_in, path.y_in, color="tab:blue", lw=1.0, label=f"tip path ({path.speed_in_per_s:g} in/s)")
    if traj is not None:
        wx = [w.x_in for w in traj.waypoints]
        wy = [w.y_in for w in traj.waypoints]
        ax.plot(wx, wy, "o", ms=3, color="tab:orange", label="way-points")
        ax.plot(wx[:1], wy[:1], "s", ms=7, mfc="none", color="tab:red", label="start")
        for w in traj.waypoints:
            if w.pause_s > 0:
                ax.annotate(f"pause {w.pause_s:g} s", (w.x_in, w.y_in), textcoords="offset points", xytext=(5, 5), fontsize=7)
    if zoom and (path is not None or traj is not None):
        if path is not None:
            xs, ys = path.x_in, path.y_in
        else:
            xs = np.array([w.x_in for w in traj.waypoints])  # type: ignore[union-attr]
            ys = np.array([w.y_in for w in traj.waypoints])  # type: ignore[union-attr]
        pad = 0.15 * max(float(np.ptp(xs)), float(np.ptp(ys)), 1.0)
        ax.set_xlim(float(xs.min()) - pad, float(xs.max()) + pad)
        ax.set_ylim(float(ys.min()) - pad, float(ys.max()) + pad)
    ax.set_aspect("equal", adjustable="box" if zoom else "datalim")
    ax.set_xlabel("x (in)")
    ax.set_ylabel("y (in)")
    ax.set_title(title or (f"{traj.name} in the RALF workspace" if traj is not None else "RALF workspace"))
    ax.grid(True, lw=0.3)
    ax.legend(loc="best", fontsize=8)
    out = Path(png_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    return out
