"""How long a lap of the arm's trajectory lasts: a run given in laps (the controller's
``repeats``) lasts ``repeats * lap_seconds(...)`` simulated seconds."""

from __future__ import annotations

from pathlib import Path

from controller.trajectory import DEFAULT_TRAJECTORY_PATH, load_trajectory, sample_trajectory

__all__ = ["lap_seconds"]


def lap_seconds(speed_in_s: float = 5.0, trajectory: str | Path | None = None, sample_period_s: float = 0.005) -> float:
    """Duration of one lap of the trajectory at ``speed_in_s`` (42 s at 5 in/s, 51 s at 4 in/s for the loop)."""
    traj = load_trajectory(trajectory or DEFAULT_TRAJECTORY_PATH)
    sampled = sample_trajectory(traj, sample_period_s, speed_in_per_s=speed_in_s)
    return len(sampled.joints.phi) * sample_period_s
