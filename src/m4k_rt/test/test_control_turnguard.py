"""The turn guard: free turn angles against the outline, the yaw-rate caps, the near points."""

from __future__ import annotations

import math
import pathlib

import pytest
import yaml

from m4k_rt.control.base import BaseController, MODE_OBSTACLE
from m4k_rt.control.footprint import outline
from m4k_rt.control.memory import LASER, LASER_RADIUS, ObstacleMemory
from m4k_rt.control.params import control_params
from m4k_rt.control.turnguard import (
    CONTACT_MARGIN,
    make_turn_guard,
    near_points,
    SweepTable,
    turn_reach,
    TurnGuard,
)
from m4k_rt.protocol import ODOM_GUARD, ODOM_SLOWDOWN

M4K = outline(0.45, 0.28, 0.40, 0.1016, 0.05)    # body + wheels (m4k_rt.control.footprint)
MARGIN = 0.05
STEP = 2.0 * math.pi / 360


def _inside(x: float, y: float, poly) -> bool:
    inside = False
    for (ax, ay), (bx, by) in zip(poly, poly[1:] + poly[:1], strict=True):
        if (ay > y) != (by > y) and x < ax + (y - ay) * (bx - ax) / (by - ay):
            inside = not inside
    return inside


def _near(x: float, y: float, poly, margin: float) -> bool:
    """Brute force: the point inside the outline or within ``margin`` of an edge."""
    if _inside(x, y, poly):
        return True
    for (ax, ay), (bx, by) in zip(poly, poly[1:] + poly[:1], strict=True):
        dx, dy = bx - ax, by - ay
        t = max(0.0, min(1.0, ((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)))
        if math.hypot(x - ax - t * dx, y - ay - t * dy) < margin:
            return True
    return False


def _true_free(x: float, y: float, sense: int, margin: float = MARGIN) -> float:
    """Brute force: turn the robot in 0.1 deg steps until the point is within the margin."""
    step = math.radians(0.1)
    for n in range(3601):
        a = sense * n * step          # the robot turns by a: the point turns by -a
        c, s = math.cos(-a), math.sin(-a)
        if _near(c * x - s * y, s * x + c * y, list(M4K), margin):
            return n * step
    return math.inf


@pytest.mark.parametrize('x,y', [(0.20, 0.20), (0.0, 0.30), (0.30, 0.0), (-0.20, 0.20),
                                 (0.12, -0.26), (-0.27, -0.05), (0.05, 0.29)])
def test_the_table_never_allows_more_turn_than_the_outline_does(x, y):
    """Each way the tabulated free angle is at most the true one, and at most 5 deg short.

    (Where the ring grazes a corner its 1 cm width costs the most angle: 3.2 deg at 0.29 m.)
    """
    table = SweepTable(M4K, MARGIN)
    k, j = table.cell(math.hypot(x, y), math.atan2(y, x))
    assert k >= 0
    for free, sense in ((table.ccw[k][j], 1), (table.cw[k][j], -1)):
        true = _true_free(x, y, sense)
        assert free <= true + 1e-9
        assert free >= true - 5 * STEP


def test_points_beyond_the_sweep_cannot_be_met_and_points_at_the_outline_block_both_ways():
    table = SweepTable(M4K, MARGIN)
    corner = math.hypot(0.225, 0.14)
    assert table.reach == pytest.approx(corner + MARGIN)
    assert table.cell(table.reach + 0.02, 0.3)[0] == -1
    # 1 cm beside the left wheel's face: any turn brings a wheel or a corner within the margin
    k, j = table.cell(0.235, math.pi / 2)
    assert table.blocked[k][j]
    assert table.ccw[k][j] == 0.0 and table.cw[k][j] == 0.0


def _guard() -> TurnGuard:
    return TurnGuard(M4K, enabled=True, margin=MARGIN, reaction_time=0.8, angular_brake=7.5,
                     angular_slow=1.85, floor=0.19, release=0.19)


def _memory(*points: tuple[float, float]) -> ObstacleMemory:
    m = ObstacleMemory(16)
    for x, y in points:
        m.add_robot_point(x, y, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    return m


def test_a_leg_at_the_front_corner_stops_a_turn_toward_it_not_away():
    g = _guard()
    leg = _memory((0.20, 0.20))
    g.evaluate((leg,), 0.0, 0.0, 0.0, 0.0)
    assert g.ccw_cap == 0.0                  # toward: the corner is 4.5 cm from it
    assert g.cw_cap > g.floor                # away: the point swings off toward the wheel's
    # already turning toward it at 0.8 rad/s: a stop (counted), held while the robot brakes
    g.evaluate((leg,), 0.0, 0.0, 0.0, 0.8)
    assert (g.ccw_cap, g.ccw_held, g.stops) == (0.0, True, 1)


def test_the_cap_slows_the_turn_as_the_free_angle_shrinks_and_stops_it_in_time():
    g = _guard()
    caps = []
    for deg in (80, 60, 40, 25, 15, 10, 5):
        # a point ahead-left of the front corner at the bearing that leaves ``deg`` of turn
        a = math.radians(deg)
        caps.append(g._cap(a, 0.0, False)[0])
    assert caps == sorted(caps, reverse=True)
    assert caps[-1] == 0.0
    for deg, cap in zip((80, 60, 40, 25, 15, 10, 5), caps, strict=True):
        # every cap above zero can stop within the free angle at the braking rate
        assert cap == 0.0 or g.stop_angle(cap) <= math.radians(deg) + 1e-9
    # a turn too fast for the free angle is stopped, and stays stopped until the free angle
    # exceeds the floor's stop angle plus the release
    cap, held = g._cap(math.radians(20), 1.0, False)
    assert (cap, held) == (0.0, True)
    assert g._cap(g.stop_angle(g.floor) + g.release * 0.5, 0.0, True) == (0.0, True)
    assert g._cap(g.stop_angle(g.floor) + g.release * 1.5, 0.0, True)[1] is False


def test_a_wall_hugging_point_inside_the_margin_is_measured_against_the_outline_itself():
    g = _guard()
    # 4 cm ahead of the front face, on the centre line: inside the margin (5 cm), but a turn
    # either way swings a corner at it only after some degrees
    ahead = _memory((0.265, 0.0))
    ccw, cw = g.free_angles((ahead,), 0.0, 0.0, 0.0)
    assert 0.0 < ccw < math.inf and 0.0 < cw < math.inf
    assert ccw <= _true_free(0.265, 0.0, 1, CONTACT_MARGIN) + 1e-9


def test_the_free_angle_follows_the_robots_pose():
    g = _guard()
    leg = _memory((0.20, 0.20))
    far = g.free_angles((leg,), 1.0, 0.0, 0.0)          # the robot 1 m away
    assert far == (math.inf, math.inf)
    # the robot turned 90 deg left: the leg is now at its front-right
    ccw, cw = g.free_angles((leg,), 0.0, 0.0, math.pi / 2)
    assert cw != math.inf and ccw > cw


def test_near_points_are_the_valid_steps_within_reach_thinned():
    inc = math.radians(0.352)
    amin = -inc * 341
    ranges = [0] * 683
    for i in range(300, 320):          # a wall patch 0.25 m away, 7 deg wide
        ranges[i] = 250
    ranges[500] = 3                    # an error code: not a point
    ranges[600] = 1200                 # out of reach
    pts = near_points(amin, inc, 0.02, 5.6, ranges, 0.315, 0.0)
    xy = list(zip(pts[0::2], pts[1::2], strict=True))
    assert 1 <= len(xy) <= 2           # 3 cm of wall per point
    for x, y in xy:
        assert math.hypot(x, y) == pytest.approx(0.25, abs=1e-3)


def test_the_shipped_robot_guards_turns_within_its_outline_plus_the_margin():
    config_dir = pathlib.Path(__file__).resolve().parents[3] / 'config'
    with open(config_dir / 'robot.yaml', encoding='utf-8') as f:
        robot = yaml.safe_load(f)['robot']
    with open(config_dir / 'control.yaml', encoding='utf-8') as f:
        params = control_params(yaml.safe_load(f)['control'])
    reach = turn_reach(params, robot)
    assert reach == pytest.approx(math.hypot(0.225, 0.14) + params.guard.lateral_margin)
    g = make_turn_guard(params, robot, 0.8)
    assert g.enabled
    # the floor moves the farthest corner at the forward guard's slow floor
    assert g.floor * math.hypot(0.225, 0.14) == pytest.approx(params.guard.slow_floor)
    off = make_turn_guard(control_params({'guard': {'enabled': False}}), robot, 0.8)
    assert not off.enabled


def test_the_controller_stops_a_capped_turn_after_the_ramp_and_lets_the_other_way_go():
    # the encoders below never move: with the wheel supervision on, that is a frozen encoder
    # (the PI's break-away boost reaches moving_effort in ~0.1 s, latched at ~0.25 s)
    p = control_params({'supervision': {'enabled': False}})
    ctl = BaseController(p, 0.01)
    t = 0
    for _ in range(40):
        t += 10_000_000
        ctl.encoders(0.0, 0.0, t, t)
        ctl.command(0.0, 0.8, t)
        ctl.step(t)
    assert ctl.w > 0.3
    t += 10_000_000
    ctl.encoders(0.0, 0.0, t, t)
    ctl.command(0.0, 0.8, t)
    ctl.step(t, ccw_cap=0.0)
    assert ctl.w == 0.0 and ctl.flags & ODOM_GUARD and ctl.mode == MODE_OBSTACLE
    t += 10_000_000
    ctl.encoders(0.0, 0.0, t, t)
    ctl.command(0.0, -0.8, t)
    ctl.step(t, ccw_cap=0.0, cw_cap=0.3)
    assert -0.3 <= ctl.w < 0.0 and ctl.flags & ODOM_SLOWDOWN


def test_a_stale_laser_stops_turns_both_ways_as_it_stops_forward_motion():
    g = _guard()
    g.evaluate((_memory(),), 0.0, 0.0, 0.0, 0.0, blind=True)
    assert (g.ccw_cap, g.cw_cap) == (0.0, 0.0)
    g.evaluate((_memory(),), 0.0, 0.0, 0.0, 0.0)
    assert (g.ccw_cap, g.cw_cap) == (math.inf, math.inf)


def _wall_scan(x: float) -> tuple[float, float, list[int]]:
    """Return a URG-like scan (angle_min, increment, steps) of a wall across x = ``x``."""
    inc = math.radians(360.0 / 1024)
    amin = -inc * 341
    ranges = []
    for i in range(683):
        c = math.cos(amin + i * inc)
        ranges.append(int(x / c * 1000) if c > 0.05 and x / c < 5.6 else 0)
    return amin, inc, ranges


@pytest.mark.parametrize('gap', [0.005, 0.02, 0.03, 0.045, 0.06, 0.2])
def test_a_wall_across_the_front_at_any_gap_gives_caps_and_never_raises(gap):
    """Every ring a near point can be in has an answer in both tables (a wall 3 cm off once
    raised an IndexError in the RT actuator: the contact table's rings end sooner)."""
    g = _guard()
    amin, inc, ranges = _wall_scan(0.225 + gap)
    pts = near_points(amin, inc, 0.02, 5.6, ranges, g.reach, 0.0)
    m = ObstacleMemory(64)
    for k in range(0, len(pts), 2):
        m.add_robot_point(pts[k], pts[k + 1], LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    for w in (-1.0, 0.0, 1.0):
        g.evaluate((m,), 0.0, 0.0, 0.0, w)
        assert g.ccw_cap >= 0.0 and g.cw_cap >= 0.0
    if gap < math.hypot(0.225, 0.14) - 0.225:
        # the front corners swing out past the wall: no turn either way
        assert g.ccw_cap == 0.0 and g.cw_cap == 0.0
