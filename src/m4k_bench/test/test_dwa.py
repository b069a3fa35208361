"""The DWA local planner (pure): free-space drive, the paper's obstacle, goal, safety, window."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
import pytest

from m4k_bench.planning.dwa import (
    DwaConfig,
    DwaConfigError,
    DwaInputError,
    DwaPlanner,
    dynamic_window,
    footprint_clearance,
    rollout,
    State,
)
from m4k_bench.planning.scan import PointMemory, scan_to_points, ScanError, voxel_downsample
from m4k_testing import examples

CFG = DwaConfig()
TRIANGLE = [(1.5, -0.25), (1.5, 0.25), (1.9, 0.0)]


def segment_points(segments, spacing=0.02):
    pts = []
    for x1, y1, x2, y2 in segments:
        n = int(math.hypot(x2 - x1, y2 - y1) / spacing) + 1
        k = np.linspace(0.0, 1.0, n)[:, None]
        pts.append(np.column_stack((x1 + k[:, 0] * (x2 - x1), y1 + k[:, 0] * (y2 - y1))))
    return np.vstack(pts)


def room_points():
    """Return the paper's room (Fig. 8) as a dense point cloud: panel walls and the triangle."""
    walls = [(-0.8, -1.5, 4.2, -1.5), (4.2, -1.5, 4.2, 1.5), (4.2, 1.5, -0.8, 1.5),
             (-0.8, 1.5, -0.8, -1.5)]
    tri = [(*TRIANGLE[i], *TRIANGLE[(i + 1) % 3]) for i in range(3)]
    return segment_points(walls + tri)


def drive(planner, points, pose=(0.0, 0.0, 0.0), duration=40.0, dt=0.01):
    """Run the planner at 20 Hz against a unicycle that ramps at the acceleration limits.

    Returns the rows (t, x, y, yaw, v, w, cmd_v, cmd_w, state) seen at each planning step and
    the true minimum footprint clearance of the whole run.
    """
    x, y, th = pose
    v = w = cv = cw = 0.0
    rows, track, t, next_plan = [], [], 0.0, 0.0
    while t < duration:
        if t >= next_plan - 1e-9:
            plan = planner.plan(t, (x, y, th), (v, w), points)
            cv, cw = plan.v, plan.w
            rows.append((t, x, y, th, v, w, cv, cw, plan.state))
            next_plan += CFG.dt
            if plan.state is State.GOAL_REACHED and abs(v) < 1e-6 and abs(w) < 1e-6:
                break
        v += min(max(cv - v, -CFG.acc_v * dt), CFG.acc_v * dt)
        w += min(max(cw - w, -CFG.acc_w * dt), CFG.acc_w * dt)
        x, y, th = x + v * dt * math.cos(th), y + v * dt * math.sin(th), th + w * dt
        t += dt
        track.append((x, y, th))
    worst = footprint_clearance(np.array(track), points, CFG.length, CFG.width).min()
    return rows, float(worst)


def test_free_space_drives_straight_to_the_goal():
    planner = DwaPlanner()
    planner.set_goal(2.0, 0.0)
    rows, _ = drive(planner, np.empty((0, 2)), duration=20.0)
    final = rows[-1]
    assert final[8] is State.GOAL_REACHED
    assert math.hypot(2.0 - final[1], final[2]) <= CFG.goal_tolerance + 0.01
    assert max(abs(r[2]) for r in rows) < 0.02            # no detour without obstacles
    assert max(r[6] for r in rows) == pytest.approx(CFG.max_v)   # cruises at the 0.25 m/s cap
    assert all(0.0 <= r[6] <= CFG.max_v for r in rows)


def test_goes_around_the_triangular_obstacle_to_the_goal():
    planner = DwaPlanner()
    planner.set_goal(3.0, 0.0)
    points = room_points()
    rows, worst = drive(planner, points)
    final = rows[-1]
    assert final[8] is State.GOAL_REACHED
    assert math.hypot(3.0 - final[1], final[2]) <= CFG.goal_tolerance + 0.01
    assert worst > 0.0                                     # never touched anything
    assert worst >= CFG.margin - 0.02                      # and kept (about) the margin
    # It went around: beside the obstacle the robot's centre is clear of the triangle's width.
    beside = [abs(r[2]) for r in rows if 1.5 <= r[1] <= 1.9]
    assert beside and min(beside) > 0.25 + CFG.width / 2
    assert planner.recoveries == 0


def test_stops_at_goal_within_tolerance_and_stays_stopped():
    planner = DwaPlanner()
    planner.set_goal(1.0, 0.3)
    points = np.empty((0, 2))
    rows, _ = drive(planner, points, duration=25.0)
    assert rows[-1][8] is State.GOAL_REACHED
    x, y = rows[-1][1], rows[-1][2]
    assert math.hypot(1.0 - x, 0.3 - y) <= CFG.goal_tolerance + 0.01
    # Latched: even nudged outside the tolerance the planner keeps commanding zero.
    plan = planner.plan(100.0, (x - 0.3, y, 0.0), (0.0, 0.0), points)
    assert (plan.v, plan.w, plan.state) == (0.0, 0.0, State.GOAL_REACHED)
    planner.set_goal(2.0, 0.3)
    assert planner.plan(101.0, (x, y, 0.0), (0.0, 0.0), points).state is State.MOVING


def test_without_goal_the_planner_commands_zero():
    plan = DwaPlanner().plan(0.0, (0.0, 0.0, 0.0), (0.2, 0.1), np.empty((0, 2)))
    assert (plan.v, plan.w, plan.state) == (0.0, 0.0, State.IDLE)


def test_stuck_robot_recovers_by_rotating_in_place():
    # A wall ahead, goal beyond it; the robot is held in place (as by the RT collision guard)
    # whatever it commands: after stuck_time without progress it must rotate in place.
    cfg = DwaConfig(stuck_time=1.0)
    planner = DwaPlanner(cfg)
    planner.set_goal(3.0, 0.0)
    wall = segment_points([(0.8, -1.0, 0.8, 1.0)])
    states = []
    for i in range(60):
        plan = planner.plan(i * cfg.dt, (0.0, 0.0, 0.0), (0.0, 0.0), wall)
        states.append((plan.state, plan.v, plan.w))
    rec = [s for s in states if s[0] is State.RECOVERING]
    assert rec, states
    assert all(v == 0.0 and abs(w) > 0.0 for _, v, w in rec)
    assert planner.recoveries >= 1


def test_boxed_in_robot_is_blocked_and_stands_still():
    cfg = DwaConfig(stuck_time=0.5)
    planner = DwaPlanner(cfg)
    planner.set_goal(3.0, 0.0)
    # A box just outside the footprint: no translation and no rotation is free.
    box = segment_points([(-0.25, -0.16, 0.25, -0.16), (0.25, -0.16, 0.25, 0.16),
                          (0.25, 0.16, -0.25, 0.16), (-0.25, 0.16, -0.25, -0.16)], 0.01)
    plans = [planner.plan(i * cfg.dt, (0.0, 0.0, 0.0), (0.0, 0.0), box) for i in range(30)]
    assert all((p.v, p.w) == (0.0, 0.0) for p in plans)
    assert any(p.state is State.BLOCKED for p in plans)


poses = st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-math.pi, math.pi))
velocities = st.tuples(st.floats(-0.1, 0.4), st.floats(-1.5, 1.5))
clouds = st.lists(st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)), min_size=0,
                  max_size=40)


@settings(max_examples=examples(60))
@given(pose=poses, vel=velocities, cloud=clouds)
def test_never_picks_a_colliding_arc(pose, vel, cloud):
    points = np.array(cloud, dtype=float).reshape(-1, 2)
    planner = DwaPlanner()
    planner.set_goal(3.0, 0.0)
    plan = planner.plan(0.0, pose, vel, points)
    now = float(footprint_clearance(np.array(pose), points, CFG.length, CFG.width))
    if plan.state is State.BLOCKED:
        assert (plan.v, plan.w) == (0.0, 0.0)
        return
    # Re-simulate the chosen command the way the planner claims the robot will move.
    arc = rollout(pose, np.array([[plan.v, plan.w]]), CFG.horizon, CFG.sim_step, vel,
                  (CFG.acc_v, CFG.acc_w))
    clear = footprint_clearance(arc, points, CFG.length, CFG.width).min()
    if plan.state is State.RECOVERING:
        assert plan.v == 0.0 and plan.w != 0.0
        clear = footprint_clearance(plan.arc, points, CFG.length, CFG.width).min()
    assert clear >= min(CFG.margin, now) - 1e-4


@settings(max_examples=examples(80))
@given(pose=poses, vel=velocities)
def test_commands_respect_the_dynamic_window(pose, vel):
    planner = DwaPlanner()
    planner.set_goal(-2.0, 1.0)
    plan = planner.plan(0.0, pose, vel, np.empty((0, 2)))
    v_lo, v_hi, w_lo, w_hi = dynamic_window(*vel, CFG)
    assert CFG.min_v <= plan.v <= CFG.max_v and -CFG.max_w <= plan.w <= CFG.max_w
    assert v_lo - 1e-9 <= plan.v <= v_hi + 1e-9
    assert w_lo - 1e-9 <= plan.w <= w_hi + 1e-9
    assert abs(plan.v - min(max(vel[0], CFG.min_v), CFG.max_v)) <= \
        CFG.acc_v * CFG.window_time + 1e-9


def test_an_odometry_velocity_spike_does_not_move_the_window():
    # Seen on the stack: one odom sample of 1.33 m/s, 6.3 rad/s during a 0.25 m/s cruise.
    planner = DwaPlanner()
    planner.set_goal(10.0, 0.0)
    wall = segment_points([(0.0, 0.6, 10.0, 0.6)])       # a wall along the left side
    for i in range(3):
        planner.plan(i * CFG.dt, (i * 0.0125, 0.0, 0.0), (0.25, 0.0), wall)
    plan = planner.plan(3 * CFG.dt, (0.0375, 0.0, 0.0), (1.33, 6.3), wall)
    assert plan.state is State.MOVING
    assert plan.v == pytest.approx(0.25) and abs(plan.w) < CFG.acc_w * CFG.window_time


def test_dynamic_window_is_bounded_by_limits_and_acceleration():
    assert dynamic_window(0.0, 0.0, CFG) == pytest.approx(
        (0.0, CFG.acc_v * CFG.window_time, -CFG.acc_w * CFG.window_time,
         CFG.acc_w * CFG.window_time))
    v_lo, v_hi, _, _ = dynamic_window(0.25, 0.0, CFG)
    assert (v_lo, v_hi) == pytest.approx((0.25 - CFG.acc_v * CFG.window_time, 0.25))
    # Faster than allowed (e.g. limits lowered): the window is the reachable limit.
    assert dynamic_window(5.0, 0.0, CFG)[:2] == (CFG.max_v, CFG.max_v)


def test_rollout_matches_a_circle_and_ramps_at_the_limits():
    arc = rollout((0.0, 0.0, 0.0), np.array([[0.2, 0.5]]), math.pi / 0.5, 0.05)[0]
    assert arc[-1, :2] == pytest.approx((0.0, 0.8), abs=1e-9)    # half circle of radius 0.4
    ramp = rollout((0.0, 0.0, 0.0), np.array([[0.25, 0.0]]), 1.0, 0.1, (0.0, 0.0),
                   (0.37, 1.85))[0]
    # 0.25 m/s is reached after 0.676 s at 0.37 m/s^2: 0.0845 m of ramp + 0.081 m cruise.
    assert ramp[-1, 0] == pytest.approx(0.25 ** 2 / (2 * 0.37) + 0.25 * (1 - 0.25 / 0.37),
                                        abs=2e-3)


def test_footprint_clearance_is_signed_distance_to_the_rectangle():
    pose = np.array([1.0, 0.0, math.pi / 2])   # facing +y: long axis along y
    pts = np.array([[1.0, 0.225 + 0.1], [1.0 + 0.14 + 0.2, 0.0], [1.0, 0.0]])
    d = [float(footprint_clearance(pose, pts[i:i + 1], 0.45, 0.28)) for i in range(3)]
    assert d == pytest.approx([0.1, 0.2, -0.14], abs=1e-5)
    assert footprint_clearance(pose, np.empty((0, 2)), 0.45, 0.28) == math.inf


def test_bad_inputs_raise_specific_errors():
    planner = DwaPlanner()
    planner.set_goal(1.0, 0.0)
    with pytest.raises(DwaInputError, match='pose'):
        planner.plan(0.0, (math.nan, 0.0, 0.0), (0.0, 0.0), np.empty((0, 2)))
    with pytest.raises(DwaInputError, match='velocity'):
        planner.plan(0.0, (0.0, 0.0, 0.0), (0.0, math.inf), np.empty((0, 2)))
    with pytest.raises(DwaInputError, match='goal'):
        planner.set_goal(math.nan, 0.0)
    # Non-finite points are dropped, not trusted and not fatal.
    plan = planner.plan(0.0, (0.0, 0.0, 0.0), (0.0, 0.0), np.array([[math.nan, 0.1]]))
    assert plan.state is State.MOVING


@pytest.mark.parametrize('field,value,match', [
    ('max_v', 0.0, 'max_v: must be > 0, got 0.0'),
    ('margin', math.nan, 'margin: expected a number, got nan'),
    ('w_samples', 1, 'w_samples: expected an integer >= 2, got 1'),
    ('clearance_ref', 0.01, 'clearance_ref: must be > margin'),
    ('recovery_w', 5.0, 'recovery_w: must be <= max_w'),
    ('goal_brake', 1.5, r'goal_brake: must be in \(0, 1\], got 1\.5'),
])
def test_config_rejects_bad_values_naming_the_field(field, value, match):
    with pytest.raises(DwaConfigError, match=match):
        DwaConfig(**{field: value})


def test_config_from_mapping_rejects_unknown_fields():
    assert DwaConfig.from_mapping({'max_v': 0.2}).max_v == 0.2
    with pytest.raises(DwaConfigError, match=r'dwa\.speed: unknown key \(allowed: acc_v, '):
        DwaConfig.from_mapping({'speed': 1.0})


def test_scan_points_use_the_laser_mount_and_robot_pose():
    # A laser 0.1 m ahead of base_link, robot at (1, 2) facing +y; a return straight ahead
    # at 0.5 m lands 0.6 m in front of base_link in odom: (1, 2.6). Invalid returns vanish.
    pts = scan_to_points([0.5, math.nan, 0.01, 9.0, 0.5], -math.pi / 2, math.pi / 4, 0.02, 5.6,
                         mount=(0.1, 0.0, 0.0), pose=(1.0, 2.0, math.pi / 2))
    assert len(pts) == 2
    assert pts[0] == pytest.approx((1.5, 2.1))       # angle -90 deg: to the robot's right
    assert pts[1] == pytest.approx((0.5, 2.1))       # angle +90 deg: to its left
    with pytest.raises(ScanError, match='range limits'):
        scan_to_points([1.0], 0.0, 0.1, 1.0, 0.5)
    with pytest.raises(ScanError, match='pose'):
        scan_to_points([1.0], 0.0, 0.1, 0.0, 5.0, pose=(0.0, math.inf, 0.0))


def test_point_memory_forgets_old_scans_but_keeps_the_newest():
    mem = PointMemory(memory_s=1.0, resolution=0.05)
    mem.add(0.0, np.array([[1.0, 0.0]]))
    mem.add(0.5, np.array([[2.0, 0.0], [2.01, 0.0]]))      # same 5 cm cell: one point
    assert len(mem.points(1.0)) == 2
    assert mem.points(1.2).tolist() == [[2.0, 0.0]]
    assert mem.points(10.0).tolist() == [[2.0, 0.0]]      # the newest stays, however old
    mem.clear()
    assert len(mem.points(0.0)) == 0
    assert len(voxel_downsample(np.array([[0.0, 0.0], [0.001, 0.0]]), 0.05)) == 1


def test_old_odometry_brakes_earlier_for_the_goal():
    # The same state seen through stale odometry: the robot has already gone on for ``age``
    # at its speed, so the planner must slow down sooner (no overshoot on a loaded machine).
    def v_at(age):
        planner = DwaPlanner()
        planner.set_goal(0.2, 0.0)
        return planner.plan(0.0, (0.0, 0.0, 0.0), (0.25, 0.0), np.empty((0, 2)), age=age).v

    fresh, stale = v_at(0.0), v_at(0.4)
    assert stale < fresh
    assert v_at(float('nan')) == fresh and v_at(-1.0) == fresh   # nonsense ages count as 0
