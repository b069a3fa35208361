import math

import pytest

from m4k_rt.control.guard import CollisionGuard, GuardError
from m4k_rt.control.params import ControlParams

MS = 1_000_000
INF = math.inf
NOW = 10_000 * MS


_DEFAULTS = ControlParams()


def guard(**kw):
    """A guard with the declared defaults (GuardParams), no slow-down, t_react 0.48 s."""
    g = _DEFAULTS.guard
    for name in ('enabled', 'stop_distance', 'release_margin', 'slow_floor',
                 'brake_deceleration', 'use_sonar', 'use_laser', 'sonar_timeout',
                 'laser_timeout', 'stale_policy'):
        kw.setdefault(name, getattr(g, name))
    kw.setdefault('slow_down', False)
    kw.setdefault('slow_deceleration', _DEFAULTS.linear.max_deceleration)
    kw.setdefault('reaction_time', 0.48)
    return CollisionGuard(**kw)


def test_clear_path_does_not_limit():
    g = guard()
    assert g.evaluate(NOW, 2.0, 1.5, NOW - 5 * MS, 3.0, NOW - 50 * MS) == INF
    assert not g.active


def test_sonar_below_stop_distance_stops_forward():
    g = guard()
    assert g.evaluate(NOW, 2.0, 0.30, NOW, 3.0, NOW) == 0.0
    assert g.active
    assert g.activations == 1


def test_laser_front_min_below_stop_distance_stops_forward():
    g = guard()
    assert g.evaluate(NOW, 2.0, INF, NOW, 0.2, NOW) == 0.0


def test_hysteresis_releases_only_beyond_margin():
    g = guard()
    g.evaluate(NOW, 2.0, 0.30, NOW, INF, NOW)
    assert g.evaluate(NOW, 2.0, 0.38, NOW, INF, NOW) == 0.0   # inside the margin: still stopped
    assert g.active
    assert g.evaluate(NOW, 2.0, 0.41, NOW, INF, NOW) != 0.0
    assert not g.active
    assert g.evaluate(NOW, 2.0, 0.36, NOW, INF, NOW) != 0.0   # above stop: stays released


def test_release_waits_until_the_slow_floor_could_move_without_tripping_again():
    """Stopped at a wall on the slow-down approach, a held forward command and sonar noise of a
    few mm must not release the guard: the robot would set off at the slow floor and trip again
    at once (stop-go chatter, seen on the stack at 0.39 m with a 0.40 m release)."""
    g = guard(slow_down=True, reaction_time=0.48, brake_deceleration=1.5, slow_floor=0.05)
    floor_d = g.stop_distance_at(0.05)          # 0.05 * 0.48 + 0.05^2 / 3 + 0.35 = 0.3748
    assert floor_d == pytest.approx(0.05 * 0.48 + 0.05 ** 2 / 3.0 + 0.35)
    assert g.evaluate(NOW, 2.0, 0.39, NOW, INF, NOW, speed=0.09) == 0.0     # tripped at 0.09
    for d in (0.395, 0.40, 0.41, floor_d + 0.049):      # noise at rest: still stopped
        assert g.evaluate(NOW, 2.0, d, NOW, INF, NOW, speed=0.0) == 0.0, d
    cap = g.evaluate(NOW, 2.0, floor_d + 0.051, NOW, INF, NOW, speed=0.0)
    assert not g.active and cap >= 0.05
    # moving off at the cap it gives, it is not inside the stop zone
    assert g.evaluate(NOW, 2.0, floor_d + 0.051, NOW, INF, NOW, speed=cap) == cap


def test_a_trip_holds_while_the_robot_brakes_unless_the_way_ahead_clears():
    """Tripped 5 mm inside the line at 0.5 m/s by a static panel: as the robot brakes, the
    stop zone at its falling speed shrinks below the panel's distance. That is no release (it
    was one: the robot drove on at the slow-down cap, a brake-and-go toward the panel); the
    trip holds until the robot has braked to the slow floor, then the at-rest rule applies.
    A way ahead that really clears (the obstacle beyond the trip's zone) releases at once."""
    g = guard(slow_down=True, reaction_time=0.48, brake_deceleration=1.5, slow_floor=0.05)
    d0 = g.stop_distance_at(0.5)
    assert g.evaluate(NOW, 2.0, d0 - 0.005, NOW, INF, NOW, speed=0.5) == 0.0
    travelled = 0.0
    for v in (0.45, 0.4, 0.33, 0.25, 0.15, 0.08):      # braking; the zone falls below the gap
        travelled += 0.01
        gap = d0 - 0.005 - travelled
        assert g.stop_distance_at(v) < gap or v > 0.3
        assert g.evaluate(NOW, 2.0, gap, NOW, INF, NOW, speed=v) == 0.0, v
    # braked to the slow floor at a gap beyond the at-rest release: the at-rest rule
    cap = g.evaluate(NOW, 2.0, d0 - 0.07, NOW, INF, NOW, speed=0.04)
    assert not g.active and cap >= 0.05
    # a person walking out of the corridor mid-brake: released at once
    g2 = guard(slow_down=True, reaction_time=0.48, brake_deceleration=1.5, slow_floor=0.05)
    assert g2.evaluate(NOW, 2.0, 0.6, NOW, INF, NOW, speed=0.5) == 0.0
    assert g2.evaluate(NOW, 2.0, 0.62, NOW, INF, NOW, speed=0.4) == 0.0   # still there
    assert g2.evaluate(NOW, 2.0, INF, NOW, INF, NOW, speed=0.35) == INF
    assert not g2.active


def test_stop_zone_grows_with_speed():
    g = guard(slow_down=False, reaction_time=0.5, brake_deceleration=2.0)
    # d(1 m/s) = 0.5 + 1/4 + 0.35 = 1.1 m: an obstacle at 1.0 m stops a robot at 1 m/s ...
    assert g.evaluate(NOW, 2.0, 1.0, NOW, INF, NOW, speed=1.0) == 0.0
    assert g.trip_distance == pytest.approx(1.1)
    g2 = guard(slow_down=False, reaction_time=0.5, brake_deceleration=2.0)
    # ... but not one at 0.1 m/s (d = 0.05 + 0.0025 + 0.35)
    assert g2.evaluate(NOW, 2.0, 1.0, NOW, INF, NOW, speed=0.1) == INF


def test_stop_distance_and_its_inverse_agree():
    from m4k_rt.control.guard import speed_for_distance, stop_distance
    for v in (0.0, 0.1, 0.5, 1.0, 2.0, 3.3):
        d = stop_distance(v, 0.48, 1.5, 0.35)
        assert speed_for_distance(d, 0.48, 1.5, 0.35) == pytest.approx(v, abs=1e-9)
    assert speed_for_distance(0.2, 0.48, 1.5, 0.35) == 0.0
    assert speed_for_distance(INF, 0.48, 1.5, 0.35) == INF


def test_slow_down_cap_lets_the_ramp_stop_in_time():
    from m4k_rt.control.guard import stop_distance
    g = guard(slow_down=True, reaction_time=0.48, brake_deceleration=1.5,
              slow_deceleration=0.37)
    cap = g.evaluate(NOW, 2.0, 1.5, NOW, INF, NOW, speed=0.0)
    assert 0.0 < cap < 2.0 and g.slowing and not g.active
    # at the cap, the ramp's own deceleration stops the robot within the distance seen
    assert stop_distance(cap, 0.48, 0.37, 0.35) == pytest.approx(1.5)
    # and the stop zone (harder braking) would still let it pass: slowing, not stopping
    assert stop_distance(cap, 0.48, 1.5, 0.35) < 1.5
    assert g.evaluate(NOW, 2.0, 0.36, NOW, INF, NOW, speed=0.0) == pytest.approx(0.05)  # floor
    assert g.evaluate(NOW, 2.0, 9.0, NOW, 9.0, NOW, speed=0.0) == INF
    assert not g.slowing


def test_weakened_guard_stops_that_much_later_but_never_weakens_a_stale_stop():
    g = guard(slow_down=False, weaken=0.1)
    assert g.evaluate(NOW, 2.0, 0.30, NOW, INF, NOW) == INF      # 0.40 seen as 0.40 > 0.35
    assert g.evaluate(NOW, 2.0, 0.24, NOW, INF, NOW) == 0.0
    g2 = guard(weaken=0.1, slow_down=True)
    assert g2.evaluate(NOW, 2.0, 3.0, 0, INF, NOW) == 0.0       # stale sonar: still stops


def test_stale_sensor_stops_forward_with_stop_policy():
    g = guard(sonar_timeout=0.2)
    assert g.evaluate(NOW, 2.0, 3.0, NOW - 250 * MS, 3.0, NOW) == 0.0
    assert g.sonar_stale and g.active
    # never reported is stale too
    g2 = guard()
    assert g2.evaluate(NOW, 2.0, INF, 0, INF, NOW) == 0.0


def test_stale_sensor_is_ignored_with_ignore_policy():
    g = guard(stale_policy='ignore')
    assert g.evaluate(NOW, 2.0, 0.1, NOW - 1000 * MS, 3.0, NOW) == INF
    assert g.sonar_stale and not g.active
    assert g.evaluate(NOW, 2.0, 0.1, 0, 0.1, 0) == INF


def test_disabled_guard_and_unused_sensor():
    assert guard(enabled=False).evaluate(NOW, 2.0, 0.0, NOW, 0.0, NOW) == INF
    g = guard(use_sonar=False)
    assert g.evaluate(NOW, 2.0, 0.0, 0, 2.0, NOW) == INF


@pytest.mark.parametrize('kw,field', [
    ({'stop_distance': -0.1}, 'stop_distance'),
    ({'brake_deceleration': 0.0}, 'brake_deceleration'),
    ({'weaken': -0.1}, 'weaken'),
    ({'sonar_timeout': 0.0}, 'sonar_timeout'),
    ({'stale_policy': 'maybe'}, 'stale_policy'),
    ({'release_margin': math.nan}, 'release_margin'),
])
def test_bad_parameters_are_rejected(kw, field):
    with pytest.raises(GuardError, match=field):
        guard(**kw)


def _scan(ranges, inc_deg=0.352):
    inc = math.radians(inc_deg)
    n = len(ranges)
    return -(n // 2) * inc, inc, 0.02, 5.6, ranges


@pytest.mark.parametrize('lateral', [0.0, 0.05, 0.10, 0.13, -0.13, 0.17, -0.17])
@pytest.mark.parametrize('ahead', [0.05, 0.5, 1.5, 3.0, 5.0])
def test_corridor_sees_a_4cm_leg_anywhere_across_the_front_face(ahead, lateral):
    from m4k_rt.control.guard import FrontCorridor
    # URG-04LX geometry: 0.352 deg steps; the laser 0.225 m behind the face; half width
    # 0.14 + 0.05 margin. A 4 cm round leg whose centre is ``ahead`` of the face (its near
    # surface 2 cm closer) and ``lateral`` off the centre line: every beam that hits it.
    corridor = FrontCorridor(0.19, 0.225)
    inc = math.radians(360.0 / 1024)
    n = 683
    angle_min = -384 * inc
    cx, cy, rad = 0.225 + ahead, lateral, 0.02
    ranges = []
    for i in range(n):
        a = angle_min + i * inc
        ca, sa = math.cos(a), math.sin(a)
        proj = cx * ca + cy * sa
        perp2 = cx * cx + cy * cy - proj * proj
        if proj > 0 and perp2 <= rad * rad:
            ranges.append(int((proj - math.sqrt(rad * rad - perp2)) * 1000))
        else:
            ranges.append(0)                  # nothing within 5.6 m
    got = corridor.minimum(angle_min, inc, 0.02, 5.6, ranges)
    assert got == pytest.approx(max(ahead - rad, 0.0), abs=0.01)


def test_corridor_ignores_walls_beside_it_and_points_beyond_the_face_width():
    from m4k_rt.control.guard import FrontCorridor
    corridor = FrontCorridor(0.19, 0.225)
    # a corridor wall 0.30 m to the left, parallel: never inside the swept corridor
    inc = math.radians(360.0 / 1024)
    angle_min = -384 * inc
    ranges = []
    for i in range(683):
        a = angle_min + i * inc
        s = math.sin(a)
        ranges.append(int(0.30 / s * 1000) if s > 0.05 and 0.30 / s < 5.6 else 0)
    assert corridor.minimum(angle_min, inc, 0.02, 5.6, ranges) == INF


def test_corridor_skips_error_codes_and_out_of_range_values():
    from m4k_rt.control.guard import FrontCorridor
    corridor = FrontCorridor(0.19, 0.0)
    inc = math.radians(1.0)
    angle_min = math.radians(-120.0)
    ranges = [0] * 241                  # -120 .. +120 deg in 1 deg steps, nothing in range
    ranges[120 + 10] = 7                # +10 deg: URG error code, not a distance
    ranges[120] = 6000                  # beyond range_max: not a measurement
    assert corridor.minimum(angle_min, inc, 0.02, 5.6, ranges) == INF
    ranges[120 - 5] = 1200              # -5 deg, 1.2 m: 0.105 m off the centre line: inside
    ahead = 1.2 * math.cos(math.radians(5.0))
    assert corridor.minimum(angle_min, inc, 0.02, 5.6, ranges) == pytest.approx(ahead)


def test_corridor_nothing_in_range_and_error_codes_only_are_inf():
    from m4k_rt.control.guard import FrontCorridor, GuardError
    corridor = FrontCorridor(0.19, 0.225)
    # code 0: "object possibly at 22 m" -- nothing within 5.6 m: free, like the sonar's no echo
    assert corridor.minimum(-2.0, 0.01, 0.02, 5.6, [0] * 401) == INF
    # only error codes ahead (a black surface): measured nothing -- the other sensor is the
    # witness
    assert corridor.minimum(-2.0, 0.01, 0.02, 5.6, [2] * 401) == INF
    assert corridor.minimum(-2.0, 0.01, 0.02, 5.6, [1] * 401) == INF
    assert corridor.minimum(1.0, 0.01, 0.02, 5.6, [500] * 10) == INF   # not scanned ahead
    with pytest.raises(GuardError, match='half width'):
        FrontCorridor(0.0)


def test_corridor_measures_from_the_front_face_not_the_laser():
    from m4k_rt.control.footprint import half_width_of
    from m4k_rt.control.guard import front_offset, FrontCorridor
    robot = {'body': {'length': 0.45, 'width': 0.28},
             'sensors': {'laser': {'pose': [0.0, 0, 0.2, 0, 0, 0]},
                         'sonar': {'pose': [0.225, 0, 0.1, 0, 0, 0]}}}
    assert front_offset(robot, 'laser') == pytest.approx(0.225)
    assert front_offset(robot, 'sonar') == 0.0
    assert front_offset({}, 'laser') == 0.0                      # no robot section: as measured
    assert half_width_of(robot, 0.40) == pytest.approx(0.20)    # no wheel width: the centres
    corridor = FrontCorridor(0.19, 0.225)
    inc = math.radians(1.0)
    ranges = [0] * 241
    ranges[120] = 575                   # straight ahead, 0.575 m from the laser: 0.35 m gap
    assert corridor.minimum(math.radians(-120.0), inc, 0.02, 5.6, ranges) == pytest.approx(0.35)
