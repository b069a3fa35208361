"""The arc corridor: gaps along the arc the robot drives (m4k_rt.control.arc)."""

from __future__ import annotations

import math

import pytest

from m4k_rt.control.arc import arc_gap, arc_points, CURVATURES, nearest_on_arc
from m4k_rt.control.memory import LASER, LASER_RADIUS, ObstacleMemory

HW = 0.275      # the corridor: the wheels' faces + the lateral margin
FRONT = 0.225   # the front face's x


def test_a_gentle_arc_measures_what_the_straight_corridor_does():
    assert arc_gap(2.0, 0.1, 1e-4, HW, FRONT) == pytest.approx(2.0 - FRONT, abs=0.01)
    assert arc_gap(2.0, -0.1, -1e-4, HW, FRONT) == pytest.approx(2.0 - FRONT, abs=0.01)


def test_a_point_on_the_arc_is_as_far_as_the_arc_before_the_face_meets_it():
    r = 2.0
    a = 1.0                                   # 1 rad along a left arc of 2 m
    px, py = r * math.sin(a), r * (1.0 - math.cos(a))
    expected = r * (a - math.asin(FRONT / r))
    assert arc_gap(px, py, 1.0 / r, HW, FRONT) == pytest.approx(expected, rel=1e-9)
    # the mirror image on a right arc
    assert arc_gap(px, -py, -1.0 / r, HW, FRONT) == pytest.approx(expected, rel=1e-9)
    # off the band (0.4 m inside the arc), behind the robot, or beside the face: never met
    ix, iy = (r - 0.4) * math.sin(a), r - (r - 0.4) * math.cos(a)
    assert arc_gap(ix, iy, 1.0 / r, HW, FRONT) == math.inf
    assert arc_gap(-1.0, 0.2, 1.0 / r, HW, FRONT) == math.inf
    assert arc_gap(0.1, 0.2, 1.0 / r, HW, FRONT) == math.inf


def test_a_leg_on_the_arc_outside_the_straight_corridor_is_seen_along_the_arc():
    """On a 2 m arc a leg 1.2 m along lies 0.36 m off the straight line: outside the straight
    corridor (0.275 m), 0.97 m ahead along the arc."""
    r = 2.0
    a = 0.6
    px, py = r * math.sin(a), r * (1.0 - math.cos(a))
    assert py > HW                                  # the straight corridor does not see it
    inc = math.radians(360.0 / 1024)
    amin = -inc * 341
    bearing = math.atan2(py, px)
    rng = math.hypot(px, py)
    ranges = [0] * 683
    for i in range(683):
        if abs(amin + i * inc - bearing) <= math.asin(0.015 / rng):
            ranges[i] = int(rng * 1000)
    pts = arc_points(amin, inc, 0.02, 5.6, ranges, 0.0, HW, FRONT)
    assert 2 <= len(pts) <= 2 * len(CURVATURES)
    m = ObstacleMemory(16)
    for k in range(0, len(pts), 2):
        m.add_robot_point(pts[k], pts[k + 1], LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    gap = nearest_on_arc(m, 1.0 / r, HW, FRONT, 0.0, 0.0, 0.0, 5.0)
    assert gap == pytest.approx(r * (a - math.asin(FRONT / r)), abs=0.03)
    # the same memory seen from a robot driving straight or turning the other way: not ahead
    assert nearest_on_arc(m, -1.0 / r, HW, FRONT, 0.0, 0.0, 0.0, 5.0) == math.inf
    # beyond the horizon it is not looked at
    assert nearest_on_arc(m, 1.0 / r, HW, FRONT, 0.0, 0.0, 0.0, 0.5) == math.inf


def test_the_curvature_of_a_motion_is_an_arc_only_when_it_drives_forward_and_bends():
    from m4k_rt.control.arc import curvature, MIN_SPEED, STRAIGHT
    assert curvature(1.0, 0.5) == pytest.approx(0.5)
    assert curvature(1.0, -0.5) == pytest.approx(-0.5)
    assert curvature(MIN_SPEED / 2, 0.02) == 0.0         # creeping: no arc
    assert curvature(-0.1, 0.5) == 0.0                   # reversing
    assert curvature(2.0, STRAIGHT) == 0.0               # straight within a centimetre
    assert curvature(0.2, 1.5) == max(CURVATURES)        # tighter: the tightest kept arc


def test_the_feed_measures_the_commands_arc_when_it_bends_otherwise():
    from m4k_rt.control.sightings import SightingFeed
    feed = SightingFeed(ObstacleMemory(16), sonar_x=FRONT, laser_x=0.0, front_x=FRONT,
                        half_width=HW, sonar_half_angle=0.13, sonar_reach=4.5)
    r, a = 2.0, 0.6
    feed.memory.add_robot_point(r * math.sin(a), r * (1.0 - math.cos(a)), LASER, LASER_RADIUS,
                                0.0, 0.0, 0.0)
    on_arc = r * (a - math.asin(FRONT / r))
    # driving straight, told to turn left on the 2 m arc: the command's arc finds it
    assert feed.nearest_on_arcs(1.0, 0.0, 1.0, 0.5, 0.0, 0.0, 0.0, 1.5) == pytest.approx(
        on_arc, abs=0.01)
    # turning right and told to go on doing so: neither arc meets it
    assert feed.nearest_on_arcs(1.0, -0.5, 1.0, -0.5, 0.0, 0.0, 0.0, 1.5) == math.inf


def test_an_arc_that_drifts_less_than_the_margin_over_the_stop_zone_is_straight():
    from m4k_rt.control.arc import curvature, DRIFT
    # a heading correction (w 0.05 at 0.5 m/s: R 10 m) over a 0.8 m stop zone drifts 3 cm
    # -> 0.032 m > DRIFT: an arc; over 0.5 m it drifts 1.25 cm: straight
    assert curvature(0.5, 0.05, 0.8) == pytest.approx(0.1)
    assert curvature(0.5, 0.05, 0.5) == 0.0
    # the same curvature over the 3.3 m stop zone at 2 m/s is an arc
    assert 0.1 * 3.3 ** 2 / 2 > DRIFT and curvature(2.0, 0.2, 3.3) == pytest.approx(0.1)
