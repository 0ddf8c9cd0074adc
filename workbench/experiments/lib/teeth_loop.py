"""A closed loop of square teeth along a line: a nearly constant arm configuration with rich excitation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from controller.trajectory import WaypointTrajectory

__all__ = ["GAP_RATIO", "square_teeth_loop"]

GAP_RATIO = 0.8
"""Each tooth is followed by a gap of this times its width."""


def square_teeth_loop(
    start_in: tuple[float, float],
    along: tuple[float, float],
    teeth: Sequence[tuple[float, float]],
    *,
    speed_in_per_s: float,
    name: str,
    description: str,
) -> WaypointTrajectory:
    """Way-points from ``start_in`` (x, y in inches) along the direction ``along``: per tooth ``(width, height)``
    in inches a rise, a top, a fall, then a gap of :data:`GAP_RATIO` × its width; the teeth stand on the side
    of increasing y; closed (the last point returns along the base line), a 1-s pause at the start."""
    p0 = np.array(start_in)
    u = np.array(along) / np.hypot(*along)
    nrm = np.array([-u[1], u[0]])
    if nrm[1] < 0:
        nrm = -nrm
    pts = [(0.0, 0.0)]
    s = 0.0
    for w, h in teeth:
        s += w
        pts += [(s, 0.0), (s, h)]
        s += GAP_RATIO * w
        pts += [(s, h), (s, 0.0)]
    wps = []
    for i, (a, b) in enumerate(pts):
        p = p0 + a * u + b * nrm
        wps.append({"x_in": round(float(p[0]), 3), "y_in": round(float(p[1]), 3), "pause_s": 1.0 if i == 0 else 0.0})
    return WaypointTrajectory(name=name, description=description, speed_in_per_s=speed_in_per_s, closed=True, waypoints=wps)
