"""The guard's obstacle memory: carried with the robot, forgotten only when seen free, bounded."""

from __future__ import annotations

import math

import pytest

from m4k_rt.control.guard import CollisionGuard, FrontCorridor
from m4k_rt.control.memory import LASER, LASER_RADIUS, ObstacleMemory, scan_frees, SONAR
from m4k_rt.control.sightings import LaserSighting, PoseHistory, SightingFeed, SonarSighting

HALF = math.radians(7.5)     # the US-100's half cone
HW = 0.19                    # corridor half width (0.14 body + 0.05 margin)
FRONT = 0.225                # the front face's x (the sonar sits on it)
MS = 1_000_000

# A scan like the URG-04LX's: 0.352 deg steps over +-120 deg, the laser on the axle.
INC = math.radians(360.0 / 1024)
AMIN = -INC * 341
N = 683


def scan(objects: list[tuple[float, float, int]] | None = None, far: int = 0) -> list[int]:
    """Return URG steps seeing each (x, y, code) 3 cm disc from the laser; ``far`` elsewhere.

    ``code`` 0: a normal surface (the range is measured); else the error code it returns.
    """
    out = [far] * N
    for x, y, code in objects or ():
        r = math.hypot(x, y)
        a = math.atan2(y, x)
        w = math.asin(0.015 / r)
        for j in range(N):
            if abs(AMIN + j * INC - a) <= w:
                out[j] = code if code else int(r * 1000)
    return out


def feed(capacity: int = 64) -> SightingFeed:
    return SightingFeed(ObstacleMemory(capacity), sonar_x=FRONT, laser_x=0.0, front_x=FRONT,
                        half_width=HW, sonar_half_angle=HALF, sonar_reach=4.5)


def laser_rec(seq: int, t: int, ranges: list[int]) -> LaserSighting:
    corridor = FrontCorridor(HW, FRONT)
    gap = corridor.minimum(AMIN, INC, 0.02, 5.6, ranges)
    return LaserSighting(seq, t, gap, corridor.unknown, corridor.lanes(0.0), AMIN, INC, 0.02,
                         5.6, tuple(ranges))


def test_memory_capacity_must_be_a_positive_int():
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match='capacity'):
            ObstacleMemory(bad)


def test_point_is_carried_with_the_robot_motion():
    m = ObstacleMemory(8)
    m.add_robot_point(1.225, 0.1, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)   # 1 m ahead of the face
    assert m.nearest(FRONT, HW, 0.0, 0.0, 0.0) == pytest.approx(1.0)
    # 0.6 m further on: 0.4 m left
    assert m.nearest(FRONT, HW, 0.6, 0.0, 0.0) == pytest.approx(0.4)
    # turned 90 deg left at the same place: the point is to the right, out of the corridor
    assert m.nearest(FRONT, HW, 0.6, 0.0, math.pi / 2) == math.inf
    # driven past it: behind the front face, not in the way
    assert m.nearest(FRONT, HW, 1.3, 0.0, 0.0) == math.inf


def test_point_seen_from_a_turned_pose_lands_in_the_world():
    m = ObstacleMemory(8)
    # robot at (1, 1) facing +y sees a point 1 m ahead of its axle: world (1, 2)
    m.add_robot_point(1.0, 0.0, LASER, 0.0, 1.0, 1.0, math.pi / 2)
    assert m.x[0] == pytest.approx(1.0) and m.y[0] == pytest.approx(2.0)


def test_nobody_reporting_never_forgets():
    m = ObstacleMemory(8)
    m.add_robot_point(2.0, 0.15, SONAR, 0.05, 0.0, 0.0, 0.0)
    m.add_robot_point(2.0, -0.1, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    for _ in range(1000):
        assert m.nearest(FRONT, HW, 0.5, 0.0, 0.0) < 2.0
    assert m.used == 2 and m.freed == 0


def test_a_repeated_sighting_refreshes_instead_of_filling():
    m = ObstacleMemory(4)
    for k in range(100):
        m.add_robot_point(2.0 + 0.0001 * k, 0.0, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    assert m.used == 1 and m.added == 1 and m.merged == 99


def test_memory_is_bounded_and_replaces_the_farthest_point():
    m = ObstacleMemory(4)
    for k in range(4):
        m.add_robot_point(1.0 + k, 0.0, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    m.add_robot_point(0.8, 0.0, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    assert m.used == 4 and m.evicted == 1
    assert sorted(m.x) == pytest.approx([0.8, 1.0, 2.0, 3.0])     # 4.0 m went
    assert len(m.x) == 4


def test_sonar_frees_a_point_its_cone_covers_with_a_farther_echo():
    m = ObstacleMemory(8)
    m.add_robot_point(FRONT + 1.0, 0.0, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    m.free_by_sonar(1.02, FRONT, HALF, 0.0, 0.0, 0.0)       # the echo is the point itself
    assert m.used == 1
    m.free_by_sonar(2.5, FRONT, HALF, 0.0, 0.0, 0.0)        # farther: the place is free
    assert m.used == 0 and m.freed == 1


def test_sonar_no_echo_does_not_free_what_is_outside_its_cone():
    m = ObstacleMemory(8)
    m.add_robot_point(FRONT + 0.5, 0.15, SONAR, 0.05, 0.0, 0.0, 0.0)   # 17 deg off the axis
    m.free_by_sonar(4.5, FRONT, HALF, 0.0, 0.0, 0.0)
    assert m.used == 1


def test_laser_error_codes_never_free_a_point():
    m = ObstacleMemory(8)
    m.add_robot_point(1.5, 0.1, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    for code in range(1, 20):
        m.free_by_scan(0.0, AMIN, INC, 0.02, 5.6, scan(far=code), 0.0, 0.0, 0.0)
        assert m.used == 1, code
    m.free_by_scan(0.0, AMIN, INC, 0.02, 5.6, scan(far=0), 0.0, 0.0, 0.0)   # code 0: free
    assert m.used == 0


def test_laser_frees_a_point_only_when_every_beam_through_it_passes_beyond():
    m = ObstacleMemory(8)
    m.add_robot_point(1.5, 0.1, LASER, LASER_RADIUS, 0.0, 0.0, 0.0)
    m.free_by_scan(0.0, AMIN, INC, 0.02, 5.6, scan(far=1400), 0.0, 0.0, 0.0)   # shorter
    assert m.used == 1
    m.free_by_scan(0.0, AMIN, INC, 0.02, 5.6, scan([(1.5, 0.1, 0)], far=4000), 0.0, 0.0, 0.0)
    assert m.used == 1                                     # still there
    m.free_by_scan(0.0, AMIN, INC, 0.02, 5.6, scan(far=4000), 0.0, 0.0, 0.0)
    assert m.used == 0


def test_scan_frees_reads_the_scip_codes():
    assert scan_frees(0, 5000.0, 20.0, 5600.0)            # nothing within range
    assert not any(scan_frees(c, 100.0, 20.0, 5600.0) for c in range(1, 20))
    assert scan_frees(3000, 2000.0, 20.0, 5600.0)
    assert not scan_frees(1500, 2000.0, 20.0, 5600.0)
    assert not scan_frees(6000, 2000.0, 20.0, 5600.0)     # not a measurement


def test_black_leg_that_leaves_the_sonar_cone_is_remembered():
    """Issue 39: sonar saw the black leg, the cone lost it, the laser got code 2: keep it."""
    f = feed()
    leg = (4.0, 0.13)            # world, the robot starts at the origin facing +x
    t = 0
    seen = []
    for step in range(0, 340):   # 1 cm steps up to 0.6 m before the face meets the leg
        x = step * 0.01
        t += 10 * MS
        f.history.record(t, x, 0.0, 0.0)
        lx, ly = leg[0] - x, leg[1]
        # the laser: code 2 on the leg's steps, nothing within range elsewhere
        f.take_laser(laser_rec(step + 1, t, scan([(lx, ly, 2)], far=0)))
        # the sonar: the leg while it is inside the cone, else no echo
        sx = lx - FRONT
        in_cone = abs(math.atan2(ly, sx)) <= HALF
        rng = math.hypot(sx, ly) - 0.015 if in_cone else math.inf   # to the leg's surface
        f.take_sonar(SonarSighting(step + 1, t, rng, rng))
        seen.append((x, in_cone, f.nearest(x, 0.0, 0.0)))
    left_cone = [x for x, c, _ in seen if not c and x > 2.0]
    assert left_cone, 'the leg never left the cone: the test would prove nothing'
    for x, _, gap in seen:
        true_gap = leg[0] - 0.015 - x - FRONT
        if true_gap < 3.5:
            assert gap <= true_gap + 0.005, (x, gap, true_gap)


def test_glass_the_laser_sees_through_is_kept_again_by_the_next_ping():
    """The laser's valid longer range frees the sonar's points (memory notes): the glass
    stays known because the sonar, which hears it, keeps it again at its next ping."""
    f = feed()
    f.history.record(MS, 0.0, 0.0, 0.0)
    f.take_sonar(SonarSighting(1, MS, 1.5, 1.5))
    assert f.nearest(0.0, 0.0, 0.0) <= 1.5
    f.take_laser(laser_rec(1, MS, scan(far=4000)))          # the laser sees through glass
    f.take_sonar(SonarSighting(2, 2 * MS, 1.5, 1.5))       # still echoing: kept again
    assert f.nearest(0.0, 0.0, 0.0) <= 1.5


def test_a_new_record_is_taken_once():
    f = feed()
    f.history.record(MS, 0.0, 0.0, 0.0)
    rec = SonarSighting(1, MS, 1.0, 1.0)
    f.take_sonar(rec)
    f.take_sonar(rec)
    assert f.sonar_taken == 1


def test_pose_history_gives_the_pose_no_later_than_the_stamp():
    h = PoseHistory(4)
    for k in range(1, 7):
        h.record(k * 10, float(k), 0.0, 0.0)
    assert h.x[h.at(45)] == 4.0
    assert h.x[h.at(60)] == 6.0
    assert h.x[h.at(1)] == 3.0          # older than the history: the oldest kept


def test_pose_reset_carries_the_points_into_the_new_frame():
    f = feed()
    f.memory.add_robot_point(1.225, 0.0, LASER, 0.0, 2.0, 0.0, 0.0)   # world 3.225, 0
    assert f.nearest(2.0, 0.0, 0.0) == pytest.approx(1.0)
    f.rebase((2.0, 0.0, 0.0), (0.0, 0.0, 0.0))        # odometry reset at the same place
    assert f.nearest(0.0, 0.0, 0.0) == pytest.approx(1.0)


def _guard() -> CollisionGuard:
    return CollisionGuard(enabled=True, stop_distance=0.35, release_margin=0.05,
                          slow_down=True, slow_deceleration=1.0, slow_floor=0.05,
                          reaction_time=0.78, brake_deceleration=1.5, use_sonar=True,
                          use_laser=True, sonar_timeout=0.2, laser_timeout=0.7,
                          stale_policy='stop', unknown_speed=0.98)


def test_memory_gap_trips_the_guard_like_a_reading():
    g = _guard()
    now = 10**9
    cap = g.evaluate(now, 2.0, math.inf, now, math.inf, now, 1.0, memory_min=0.5)
    assert cap == 0.0 and g.active


def test_unknown_caps_forward_speed_but_open_space_does_not():
    g = _guard()
    now = 10**9
    assert g.evaluate(now, 2.0, math.inf, now, math.inf, now, 0.0) == math.inf
    assert g.evaluate(now, 2.0, math.inf, now, math.inf, now, 0.0, unknown=True) == 0.98
    assert g.unknown
    # a lower commanded maximum is below the cap: nothing to cap
    assert g.evaluate(now, 0.5, math.inf, now, math.inf, now, 0.0, unknown=True) == math.inf


def test_corridor_reports_unknown_for_error_codes_only():
    c = FrontCorridor(HW, FRONT)
    assert c.minimum(AMIN, INC, 0.02, 5.6, scan(far=0)) == math.inf and not c.unknown
    assert c.minimum(AMIN, INC, 0.02, 5.6, scan([(2.0, 0.1, 2)])) == math.inf and c.unknown
    gap = c.minimum(AMIN, INC, 0.02, 5.6, scan([(2.0, 0.1, 0)]))
    assert gap == pytest.approx(2.0 - FRONT, abs=0.02) and not c.unknown
    lanes = c.lanes(0.0)
    assert lanes and len(lanes) % 2 == 0         # the leg's nearest point in its lane(s)
    assert all(abs(y - 0.1) <= 0.02 for y in lanes[1::2])


def test_reading_is_aged_from_its_acquisition_stamp():
    g = _guard()
    now = 10 * 10**9
    acquired = now - 750 * MS        # arrived just now, taken 0.75 s ago: too old
    assert g.evaluate(now, 2.0, math.inf, now, 3.0, acquired, 0.0) == 0.0
    assert g.laser_stale
