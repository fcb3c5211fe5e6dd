"""Pure-pursuit follower, ROS-free: geometry, target selection, limits, stopping.

The robot here is a perfect kinematic integrator of the commanded body twist (1 ms steps),
so every deviation comes from the follower itself; the closed loop with the simulator's
dynamics is in test_pure_pursuit_closed_loop.py.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from ekf_localization.control.field_path import FieldPath, Waypoint
from ekf_localization.control.pure_pursuit import (
    ZERO,
    Command,
    FollowerConfig,
    PurePursuitFollower,
    circle_segment_intersections,
)
from ekf_localization.core.angles import wrap_angle

DT_NS = 10_000_000  # 100 Hz control


def line(*pts: tuple[float, float], **kw) -> FieldPath:
    return FieldPath([Waypoint(x, y) for x, y in pts], **kw)


def integrate(pose: list[float], cmd: Command, dt_ns: int = DT_NS) -> None:
    """Drive a perfect robot with the body twist for dt (1 ms Euler steps)."""
    for _ in range(dt_ns // 1_000_000):
        c, s = math.cos(pose[2]), math.sin(pose[2])
        pose[0] += (cmd.vx * c - cmd.vy * s) * 1e-3
        pose[1] += (cmd.vx * s + cmd.vy * c) * 1e-3
        pose[2] = wrap_angle(pose[2] + cmd.wz * 1e-3)


def run(follower: PurePursuitFollower, pose: list[float], max_s: float = 60.0):
    """Closed loop until done; returns [(t_ns, pose, cmd, progress, target_s, leg)]."""
    log = []
    t = 0
    while t < max_s * 1e9:
        cmd = follower.update(pose[0], pose[1], pose[2], t)
        log.append((t, list(pose), cmd, follower.progress, follower.target_s, follower.leg))
        if follower.done:
            break
        integrate(pose, cmd)
        t += DT_NS
    return log


# -- circle / segment -------------------------------------------------------------------------
def test_intersections_two_hits_sorted_and_on_the_circle():
    ts = circle_segment_intersections(0.0, 0.0, 1.0, -2.0, 0.5, 2.0, 0.5)
    assert len(ts) == 2 and ts[0] < ts[1]
    for t in ts:
        x, y = -2.0 + 4.0 * t, 0.5
        assert math.hypot(x, y) == pytest.approx(1.0)


def test_intersection_tangent_gives_one_hit():
    assert circle_segment_intersections(0.0, 0.0, 1.0, -2.0, 1.0, 2.0, 1.0) == (0.5,)
    # rounding just outside the tangent still counts as touching
    (t,) = circle_segment_intersections(0.0, 0.0, 1.0, -2.0, 1.0 + 1e-15, 2.0, 1.0 + 1e-15)
    assert t == pytest.approx(0.5)


def test_intersection_none():
    assert circle_segment_intersections(0.0, 0.0, 1.0, -2.0, 1.5, 2.0, 1.5) == ()  # passes outside
    assert circle_segment_intersections(0.0, 0.0, 1.0, -0.3, 0.0, 0.3, 0.1) == ()  # inside
    assert circle_segment_intersections(0.0, 0.0, 1.0, 2.0, 0.0, 3.0, 0.0) == ()  # line hits, segment not
    assert circle_segment_intersections(0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0) == ()  # zero length


def test_intersection_at_segment_end_points():
    assert circle_segment_intersections(0.0, 0.0, 1.0, 1.0, 0.0, 3.0, 0.0) == (0.0,)  # starts on it
    assert circle_segment_intersections(0.0, 0.0, 1.0, 3.0, 0.0, 1.0, 0.0) == (1.0,)  # ends on it
    assert circle_segment_intersections(0.0, 0.0, 1.0, -1.0, 0.0, 1.0, 0.0) == (0.0, 1.0)  # a diameter
    assert circle_segment_intersections(0.0, 0.0, 1.0, 0.0, 0.0, 4.0, 0.0) == (0.25,)  # from the centre


# -- target selection -------------------------------------------------------------------------
def test_target_is_the_furthest_intersection():
    f = PurePursuitFollower(line((0, 0), (3, 0)), FollowerConfig(lookahead_distance=0.3))
    f.update(1.0, 0.05, 0.0, 0)  # joins mid-path: first call searches the whole leg
    # the circle meets the path at x = 1 ± sqrt(0.3² − 0.05²): the one ahead is the target
    assert f.target == pytest.approx((1.0 + math.sqrt(0.09 - 0.0025), 0.0))
    assert f.progress == pytest.approx(1.0)


def test_target_is_the_nearest_point_when_the_circle_misses_the_path():
    f = PurePursuitFollower(line((0, 0), (3, 0)), FollowerConfig(lookahead_distance=0.3))
    f.update(0.8, 1.0, 0.0, 0)
    assert f.target == pytest.approx((0.8, 0.0))
    assert f.cross_track_error == pytest.approx(1.0)


def test_target_is_the_leg_end_once_inside_the_circle():
    wps = [Waypoint(0, 0), Waypoint(1, 0, stop=True), Waypoint(1, 1)]
    f = PurePursuitFollower(FieldPath(wps), FollowerConfig(lookahead_distance=0.3))
    f.update(0.8, 0.0, 0.0, 0)
    assert f.target == (1.0, 0.0)  # not the point on the next leg the circle also meets
    assert f.target_heading == pytest.approx(0.0)


def test_target_never_moves_backwards_along_the_path():
    # a hairpin: out along y = 0, back along y = 0.2 (closer than the lookahead)
    path = line((0, 0), (2, 0), (2, 0.2), (0, 0.2))
    f = PurePursuitFollower(path, FollowerConfig(lookahead_distance=0.3))
    last_target, last_progress = -1.0, -1.0
    poses = [(x, 0.0) for x in (0.0, 0.2, 0.4, 0.6)] + [(0.2, 0.0), (0.3, 0.18), (0.9, 0.1), (1.0, 0.0)]
    for k, (x, y) in enumerate(poses):  # pushed back at k = 4, next to the return leg at k = 5
        f.update(x, y, 0.0, k * DT_NS)
        assert f.target_s >= last_target and f.progress >= last_progress
        assert f.target_s < 2.0, "jumped to the return leg"
        last_target, last_progress = f.target_s, f.progress
    assert f.target_s == pytest.approx(1.0 + 0.3)  # furthest hit, on the outbound leg


def test_closed_loop_is_not_done_at_its_start_and_runs_all_cycles():
    sq = [Waypoint(0, 0), Waypoint(1, 0), Waypoint(1, 1), Waypoint(0, 1)]
    path = FieldPath(sq, closed=True, cycles=2)
    f = PurePursuitFollower(path)
    cmd = f.update(0.0, 0.0, 0.0, 0)
    assert not f.done and f.progress == 0.0 and cmd == ZERO  # Δt = 0: rate limit holds at rest
    log = run(f, [0.0, 0.0, 0.0])
    assert f.done and f.progress == pytest.approx(8.0)
    # it went round twice: progress passed through the middle of both loops
    assert any(4.4 < p < 4.6 for *_, p, _, _ in log)  # first side of the second loop


# -- control ----------------------------------------------------------------------------------
@pytest.mark.parametrize("mode", ["holonomic", "differential"])
def test_stops_cleanly_at_the_end(mode):
    path = FieldPath([Waypoint(0, 0), Waypoint(1.5, 0), Waypoint(1.5, 1.0), Waypoint(2.5, 1.0, math.pi / 2)])
    cfg = FollowerConfig(mode=mode)
    f = PurePursuitFollower(path, cfg)
    pose = [0.0, 0.0, 0.0]
    log = run(f, pose)
    assert f.done
    assert math.hypot(pose[0] - 2.5, pose[1] - 1.0) <= cfg.goal_position_tolerance
    assert abs(wrap_angle(pose[2] - math.pi / 2)) <= cfg.goal_heading_tolerance
    assert f.progress == path.length
    # arrives slowly: the approach cap (ramp, floor) one step before the end
    _, p_before, c_before, *_ = log[-2]
    d_before = math.hypot(p_before[0] - 2.5, p_before[1] - 1.0)
    cap = max(cfg.max_linear_velocity * d_before / cfg.slowdown_distance, cfg.min_approach_velocity)
    assert math.hypot(c_before.vx, c_before.vy) <= cap + 1e-9 and cap < 0.06
    for k in range(5):  # done is final: zero twist from now on
        assert f.update(pose[0] + 0.5, pose[1], pose[2], log[-1][0] + (k + 1) * DT_NS) == ZERO
    assert f.done


@pytest.mark.parametrize("mode", ["holonomic", "differential"])
def test_velocity_and_acceleration_limits(mode):
    path = line((0, 0), (1.2, 0), (1.2, 1.0), (0.2, 1.0), (0.2, 0.5))
    cfg = FollowerConfig(mode=mode, max_linear_velocity=0.8, max_angular_velocity=1.5,
                         max_linear_acceleration=1.5, max_angular_acceleration=4.0)
    log = run(PurePursuitFollower(path, cfg), [0.0, 0.0, 0.0])
    prev = None
    assert log[-1][2] == ZERO  # done: the last step from <= min_approach_velocity to 0 is immediate
    for _t, pose, cmd, *_ in log[:-1]:
        c, s = math.cos(pose[2]), math.sin(pose[2])
        # holonomic: the limits hold in the field frame; differential: in the body frame
        v = (c * cmd.vx - s * cmd.vy, s * cmd.vx + c * cmd.vy) if mode == "holonomic" else (cmd.vx, cmd.vy)
        assert math.hypot(*v) <= cfg.max_linear_velocity + 1e-9
        assert abs(cmd.wz) <= cfg.max_angular_velocity + 1e-9
        if mode == "differential":
            assert cmd.vy == 0.0 and cmd.vx >= 0.0
        if prev is not None:
            dv = math.hypot(v[0] - prev[0][0], v[1] - prev[0][1])
            assert dv <= cfg.max_linear_acceleration * DT_NS * 1e-9 + 1e-9
            assert abs(cmd.wz - prev[1]) <= cfg.max_angular_acceleration * DT_NS * 1e-9 + 1e-9
        prev = (v, cmd.wz)
    assert max(math.hypot(c.vx, c.vy) for _, _, c, *_ in log) == pytest.approx(cfg.max_linear_velocity)


def test_slows_down_on_approach():
    cfg = FollowerConfig(slowdown_distance=0.6, max_linear_velocity=1.0, max_linear_acceleration=2.0)
    path = line((0, 0), (2.0, 0))
    log = run(PurePursuitFollower(path, cfg), [0.0, 0.0, 0.0])
    a, dt = cfg.max_linear_acceleration, DT_NS * 1e-9
    checked = 0
    for _t, pose, cmd, *_ in log:
        d = 2.0 - pose[0]
        cap = max(min(1.0, d / 0.6, math.sqrt(2 * a * d)), cfg.min_approach_velocity)
        assert math.hypot(cmd.vx, cmd.vy) <= cap + a * dt + 1e-9
        checked += d < 0.6
    assert checked > 20  # the approach took many control steps
    assert max(math.hypot(c.vx, c.vy) for _, _, c, *_ in log) == pytest.approx(1.0)


def test_slows_down_before_a_sharp_corner():
    cfg = FollowerConfig(lookahead_distance=0.3, max_linear_acceleration=2.0)
    path = line((0, 0), (3.0, 0), (3.0, 3.0))
    log = run(PurePursuitFollower(path, cfg), [0.0, 0.0, 0.0])
    # 90° corner: v = sqrt(a·L / (2·sin 45°)) = 0.651 m/s from one lookahead before it
    v_corner = math.sqrt(2.0 * 0.3 / (2 * math.sin(math.pi / 4)))
    at_corner = [math.hypot(c.vx, c.vy) for _, p, c, *_ in log if p[0] >= 2.7 and p[1] < 0.05]
    assert at_corner and max(at_corner) <= v_corner + 2.0 * DT_NS * 1e-9
    assert max(math.hypot(c.vx, c.vy) for _, _, c, *_ in log) == pytest.approx(1.0)


def test_repeated_stamp_keeps_the_command():
    f = PurePursuitFollower(line((0, 0), (2, 0)))
    f.update(0.0, 0.0, 0.0, 0)
    c1 = f.update(0.0, 0.0, 0.0, DT_NS)
    assert c1.vx > 0.0
    assert f.update(0.0, 0.0, 0.0, DT_NS) == c1  # Δt = 0: no acceleration possible
    c2 = f.update(0.0, 0.0, 0.0, 3 * DT_NS)  # a 20 ms gap allows twice the change
    assert c1.vx == pytest.approx(FollowerConfig().max_linear_acceleration * 0.01)
    assert c2.vx - c1.vx == pytest.approx(FollowerConfig().max_linear_acceleration * 0.02)


def test_intermediate_stop_point_is_reached_before_going_on():
    wps = [Waypoint(0, 0), Waypoint(1.0, 0, stop=True), Waypoint(0.0, 0.0)]  # out and back
    for mode in ("holonomic", "differential"):
        cfg = FollowerConfig(mode=mode)
        log = run(PurePursuitFollower(FieldPath(wps), cfg), [0.0, 0.0, 0.0])
        switch = next(i for i, entry in enumerate(log) if entry[5] == 1)
        t, pose, cmd, *_ = log[switch]
        assert math.hypot(pose[0] - 1.0, pose[1]) <= cfg.goal_position_tolerance
        assert abs(wrap_angle(pose[2])) <= cfg.goal_heading_tolerance  # stop heading: incoming tangent
        _, p_before, before, *_ = log[switch - 1]
        d_before = math.hypot(p_before[0] - 1.0, p_before[1])
        cap = max(cfg.max_linear_velocity * d_before / cfg.slowdown_distance, cfg.min_approach_velocity)
        assert math.hypot(before.vx, before.vy) <= cap + 1e-9 and cap < 0.06  # it stops there
        assert max(p[0] for _, p, *_ in log) <= 1.0 + cfg.goal_position_tolerance  # no overshoot
        assert log[-1][1][0] == pytest.approx(0.0, abs=cfg.goal_position_tolerance)


def test_differential_turns_in_place_when_the_target_is_behind():
    cfg = FollowerConfig(mode="differential")
    f = PurePursuitFollower(line((0, 0), (2, 0)), cfg)
    pose = [0.0, 0.0, math.pi]  # facing away from the path
    t = 0
    turned = 0
    while abs(wrap_angle(pose[2])) > cfg.rotate_in_place_exit_angle:
        cmd = f.update(*pose, t)
        assert cmd.vx == 0.0 and cmd.vy == 0.0
        turned += cmd.wz != 0.0
        integrate(pose, cmd)
        t += DT_NS
        assert t < 5e9
    assert turned > 10
    assert math.hypot(pose[0], pose[1]) < 1e-12  # turned on the spot
    for _ in range(20):  # then it drives
        cmd = f.update(*pose, t)
        integrate(pose, cmd)
        t += DT_NS
    assert cmd.vx > 0.1


def test_holonomic_strafes_without_turning_when_headings_say_so():
    """Seed 000's three PIDs: a fixed heading while the path goes sideways."""
    path = FieldPath([Waypoint(0, 0, 0.0), Waypoint(0, 1.0, 0.0)])
    pose = [0.0, 0.0, 0.0]
    log = run(PurePursuitFollower(path, FollowerConfig(mode="holonomic")), pose)
    assert max(abs(p[2]) for _, p, *_ in log) < 0.01
    assert max(c.vy for _, _, c, *_ in log) == pytest.approx(1.0)  # full speed, to the left
    assert pose[1] == pytest.approx(1.0, abs=0.02)


def test_path_replaced_on_the_fly_keeps_the_motion():
    f = PurePursuitFollower(line((0, 0), (3, 0)))
    pose, t = [0.0, 0.0, 0.0], 0
    for _ in range(80):  # up to full speed
        cmd = f.update(*pose, t)
        integrate(pose, cmd)
        t += DT_NS
    assert cmd.vx == pytest.approx(1.0)
    f.reset(line((pose[0], 0.0), (pose[0] + 2.0, 0.0)), keep_motion=True)
    nxt = f.update(*pose, t)
    assert nxt.vx == pytest.approx(1.0, abs=0.03)  # no jump to zero: ramps from the last command
    f.reset(line((pose[0], 0.0), (pose[0] + 2.0, 0.0)))
    assert f.update(*pose, t + DT_NS) == ZERO  # a plain reset starts from rest


def test_non_finite_pose_is_an_error():
    f = PurePursuitFollower(line((0, 0), (1, 0)))
    with pytest.raises(ValueError, match="finite"):
        f.update(math.nan, 0.0, 0.0, 0)


def test_reset_starts_over_on_a_new_path():
    f = PurePursuitFollower(line((0, 0), (0.5, 0)))
    run(f, [0.0, 0.0, 0.0])
    assert f.done
    f.reset(line((0.5, 0), (0.5, 1.0)))
    assert not f.done and f.progress == 0.0 and f.leg == 0
    pose = [0.5, 0.0, math.pi / 2]
    run(f, pose)
    assert f.done and pose[1] == pytest.approx(1.0, abs=0.02)


@pytest.mark.parametrize("field_name, value", [
    ("mode", "mecanum"), ("lookahead_distance", 0.0), ("lookahead_distance", math.nan),
    ("max_linear_velocity", -1.0), ("max_angular_velocity", math.inf),
    ("max_linear_acceleration", 0.0), ("slowdown_distance", -0.1), ("goal_position_tolerance", 0.0),
    ("goal_heading_tolerance", -0.01), ("rotate_in_place_angle", 4.0), ("search_window_factor", 0.5),
    ("min_approach_velocity", 5.0), ("rotate_in_place_exit_angle", 2.0), ("pid_x", 1.0),
])
def test_bad_config_names_the_field(field_name, value):
    with pytest.raises(ValueError, match=field_name):
        replace(FollowerConfig(), **{field_name: value})
