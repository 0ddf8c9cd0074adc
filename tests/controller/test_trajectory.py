"""Trajectories as data (thesis §4, Fig. 4.3): timing, kinematics, joint limits, plot."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from controller.trajectory import (
    DEFAULT_TRAJECTORY_PATH,
    TrajectoryLimitError,
    WaypointTrajectory,
    check_waypoints,
    load_trajectory,
    plot_workspace,
    sample_tip_path,
    sample_trajectory,
    trajectory_duration_s,
)
from protocol import geometry

TS = 0.005


@pytest.fixture(scope="module")
def loop() -> WaypointTrajectory:
    return load_trajectory(DEFAULT_TRAJECTORY_PATH)


def path_length(traj: WaypointTrajectory) -> float:
    p = np.array([[w.x_in, w.y_in] for w in traj.waypoints])
    if traj.closed:
        p = np.vstack([p, p[:1]])
    return float(np.sum(np.hypot(*np.diff(p, axis=0).T)))


def test_default_loop_loads(loop: WaypointTrajectory) -> None:
    assert loop.name == "inspection_loop"
    assert loop.closed and loop.units == "in" and loop.speed_in_per_s == 5.0
    assert loop.waypoints[0].pause_s == 3.0 and loop.waypoints[1].pause_s == 3.0
    assert loop.with_speed(4.0).speed_in_per_s == 4.0


@pytest.mark.parametrize("speed", [4.0, 5.0])
def test_duration_is_length_over_speed_plus_pauses(loop: WaypointTrajectory, speed: float) -> None:
    expected = path_length(loop) / speed + 6.0
    assert trajectory_duration_s(loop, speed) == pytest.approx(expected, abs=1e-9)
    assert trajectory_duration_s(loop, speed, repeat=3) == pytest.approx(3 * expected, abs=1e-9)
    assert expected == pytest.approx({4.0: 51.0, 5.0: 42.0}[speed], abs=1e-4)
    st = sample_trajectory(loop, TS, speed_in_per_s=speed)
    assert st.path.duration_s == pytest.approx(math.ceil(expected / TS) * TS)
    assert len(st.path) == math.ceil(expected / TS - 1e-9) + 1


def test_waypoints_and_sampled_path_inside_limits_and_fk_of_setpoints_is_the_path(loop: WaypointTrajectory) -> None:
    check_waypoints(loop)
    st = sample_trajectory(loop, TS)
    j = st.joints
    assert np.all(geometry.within_limits(j.theta1, j.theta2))
    x, y = geometry.forward(j.theta1, j.theta2)
    np.testing.assert_allclose(x, st.path.x_in, atol=1e-9)
    np.testing.assert_allclose(y, st.path.y_in, atol=1e-9)
    t1, t2 = geometry.phi_to_theta(j.phi1, j.phi2)
    np.testing.assert_allclose(t1, j.theta1, atol=1e-12)
    np.testing.assert_allclose(t2, j.theta2, atol=1e-12)
    assert j.phi.shape == (len(st.path), 2)
    np.testing.assert_allclose(j.t_s, st.path.t_s)


@pytest.mark.parametrize("speed", [4.0, 5.0])
def test_speed_is_honoured(loop: WaypointTrajectory, speed: float) -> None:
    path = sample_tip_path(loop, TS, speed_in_per_s=speed)
    step = np.hypot(np.diff(path.x_in), np.diff(path.y_in))
    assert np.all(step <= speed * TS * (1 + 1e-9))
    moving = step > 1e-12
    # every step that does not straddle a corner or a pause boundary covers exactly v Ts
    exact = np.isclose(step, speed * TS, rtol=1e-9)
    assert exact.sum() >= moving.sum() - 2 * (len(loop.waypoints) + 2)
    assert moving.sum() * TS == pytest.approx(path_length(loop) / speed, abs=30 * TS)


def test_pauses_are_honoured(loop: WaypointTrajectory) -> None:
    path = sample_tip_path(loop, TS)
    w0, w1 = loop.waypoints[0], loop.waypoints[1]
    n_pause = int(round(3.0 / TS))
    at_start = slice(0, n_pause + 1)  # t in [0, 3 s]
    np.testing.assert_allclose(path.x_in[at_start], w0.x_in)
    np.testing.assert_allclose(path.y_in[at_start], w0.y_in)
    assert path.x_in[n_pause + 2] != w0.x_in
    seg = math.hypot(w1.x_in - w0.x_in, w1.y_in - w0.y_in) / loop.speed_in_per_s  # 8 s
    arrive = 3.0 + seg
    held = (path.t_s >= arrive + TS) & (path.t_s <= arrive + 3.0 - TS)
    assert held.sum() == pytest.approx(3.0 / TS - 1, abs=2)
    np.testing.assert_allclose(path.x_in[held], w1.x_in)
    np.testing.assert_allclose(path.y_in[held], w1.y_in)
    # the lap ends where it started
    assert path.x_in[-1] == pytest.approx(w0.x_in) and path.y_in[-1] == pytest.approx(w0.y_in)


def test_repeat_runs_laps_back_to_back_with_the_start_pause_each_lap(loop: WaypointTrajectory) -> None:
    one = sample_tip_path(loop, TS)
    two = sample_tip_path(loop, TS, repeat=2)
    lap = trajectory_duration_s(loop)
    k = int(round(lap / TS))
    assert two.duration_s == pytest.approx(2 * lap, abs=TS)
    # the second lap repeats the first (the lap is within 2e-6 s of whole samples)
    np.testing.assert_allclose(two.x_in[k : k + len(one) - 1], one.x_in[:-1], atol=1e-4)
    np.testing.assert_allclose(two.y_in[k : k + len(one) - 1], one.y_in[:-1], atol=1e-4)
    open_traj = WaypointTrajectory(name="open", speed_in_per_s=5.0, closed=False, waypoints=[{"x_in": -20, "y_in": 200}, {"x_in": -25, "y_in": 200}])
    with pytest.raises(ValueError, match="closed"):
        sample_tip_path(open_traj, TS, repeat=2)
    assert sample_tip_path(open_traj, TS).duration_s == pytest.approx(1.0)


def test_corner_blending_keeps_timing_speed_and_stays_close(loop: WaypointTrajectory) -> None:
    sharp = sample_tip_path(loop, TS)
    blend_s = 0.2
    smooth = sample_trajectory(loop, TS, corner_blend_s=blend_s).path
    assert len(smooth) == len(sharp)
    dev = np.hypot(smooth.x_in - sharp.x_in, smooth.y_in - sharp.y_in)
    v = loop.speed_in_per_s
    n_win = 2 * round(blend_s / (2 * TS)) + 1
    assert dev.max() <= v * n_win * TS / 4 + 1e-9  # the worst case is a reversal: v T / 4
    assert dev.max() > 0.05
    step = np.hypot(np.diff(smooth.x_in), np.diff(smooth.y_in))
    assert np.all(step <= v * TS * (1 + 1e-9))
    # acceleration is bounded: each velocity step becomes a ramp over the window
    vel = np.diff(np.column_stack([smooth.x_in, smooth.y_in]), axis=0) / TS
    acc = np.hypot(*np.diff(vel, axis=0).T) / TS
    assert acc.max() <= 2 * v / (n_win * TS) * (1 + 1e-6)  # a reversal changes velocity by 2 v over the window
    sharp_vel = np.diff(np.column_stack([sharp.x_in, sharp.y_in]), axis=0) / TS
    assert np.hypot(*np.diff(sharp_vel, axis=0).T).max() / TS > 10 * acc.max()


def test_limit_violations_are_clear_errors() -> None:
    outside = WaypointTrajectory(
        name="bad",
        speed_in_per_s=5.0,
        waypoints=[{"x_in": -20.0, "y_in": 200.0}, {"x_in": 100.0, "y_in": 100.0}],
    )
    with pytest.raises(TrajectoryLimitError, match=r"#1 \(100.000, 100.000\)"):
        sample_trajectory(outside)
    unreachable = WaypointTrajectory(name="far", speed_in_per_s=5.0, waypoints=[{"x_in": -20.0, "y_in": 200.0}, {"x_in": 0.0, "y_in": 300.0}])
    with pytest.raises(TrajectoryLimitError, match="unreachable"):
        sample_trajectory(unreachable)
    # both way-points inside, but the straight chord cuts through the inner (theta2 = 120 deg) boundary
    xa, ya = geometry.forward(math.radians(65.0), math.radians(118.0))
    xb, yb = geometry.forward(math.radians(95.0), math.radians(118.0))
    chord = WaypointTrajectory(name="chord", speed_in_per_s=5.0, waypoints=[{"x_in": float(xa), "y_in": float(ya)}, {"x_in": float(xb), "y_in": float(yb)}])
    check_waypoints(chord)
    with pytest.raises(TrajectoryLimitError, match="path samples outside the joint limits"):
        sample_trajectory(chord)


def test_file_validation() -> None:
    base = {"name": "t", "speed_in_per_s": 5.0, "waypoints": [{"x_in": 0, "y_in": 200}, {"x_in": 1, "y_in": 200}]}
    WaypointTrajectory.model_validate(base)
    for bad in (
        {**base, "units": "mm"},
        {**base, "speed_in_per_s": 0.0},
        {**base, "waypoints": base["waypoints"][:1]},
        {**base, "waypoints": [{"x_in": 0, "y_in": 200, "pause_s": -1}, {"x_in": 1, "y_in": 200}]},
        {**base, "extra": 1},
    ):
        with pytest.raises(ValidationError):
            WaypointTrajectory.model_validate(bad)
    with pytest.raises(ValueError):
        sample_tip_path(WaypointTrajectory.model_validate(base), TS, speed_in_per_s=-1.0)


def test_plot_workspace_writes_a_png(tmp_path: Path, loop: WaypointTrajectory) -> None:
    st = sample_trajectory(loop, TS)
    out = plot_workspace(tmp_path / "sub" / "ws.png", loop, st.path)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    zoomed = plot_workspace(tmp_path / "zoom.png", loop, st.path, zoom=True)
    assert zoomed.stat().st_size > 10_000
    assert plot_workspace(tmp_path / "empty.png").exists()
