import math

import pytest

from m4k_rt.control.guard import CollisionGuard, GuardError

MS = 1_000_000
INF = math.inf
NOW = 10_000 * MS


def guard(**kw):
    kw.setdefault('stop_distance', 0.35)
    kw.setdefault('release_margin', 0.05)
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
    assert g.evaluate(NOW, 2.0, 0.41, NOW, INF, NOW) == INF
    assert not g.active
    assert g.evaluate(NOW, 2.0, 0.36, NOW, INF, NOW) == INF   # above stop: stays released


def test_slow_zone_scales_cap_linearly():
    g = guard(slow_distance=0.85)
    # halfway between 0.35 and 0.85 -> half of max velocity
    assert g.evaluate(NOW, 2.0, 0.60, NOW, INF, NOW) == pytest.approx(1.0)
    assert g.slowing
    assert g.evaluate(NOW, 2.0, 0.90, NOW, INF, NOW) == INF


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
    ({'slow_distance': 0.2}, 'slow_distance'),
    ({'sonar_timeout': 0.0}, 'sonar_timeout'),
    ({'stale_policy': 'maybe'}, 'stale_policy'),
    ({'release_margin': math.nan}, 'release_margin'),
])
def test_bad_parameters_are_rejected(kw, field):
    with pytest.raises(GuardError, match=field):
        guard(**kw)


def test_front_sector_minimum_skips_error_codes_and_out_of_sector():
    from m4k_rt.control.guard import FrontSector
    sector = FrontSector(30.0)
    inc = math.radians(1.0)
    angle_min = math.radians(-120.0)
    ranges = [3000] * 241               # -120 .. +120 deg in 1 deg steps
    ranges[120 - 20] = 500              # -20 deg: outside the +-15 deg sector
    ranges[120 + 10] = 7                # +10 deg: URG error code, not a distance
    ranges[120 - 15] = 1200             # -15 deg: on the sector edge, counted
    assert sector.window(angle_min, inc, 241) == (105, 135)
    # the distance ahead along the heading: 1.2 m at 15 deg is 1.2 cos 15 ahead
    ahead = 1.2 * math.cos(math.radians(15.0))
    assert sector.minimum(angle_min, inc, 0.02, 5.6, ranges) == pytest.approx(ahead)
    ranges[120] = 6000                  # beyond range_max: not a measurement
    assert sector.minimum(angle_min, inc, 0.02, 5.6, ranges) == pytest.approx(ahead)


def test_front_sector_nothing_in_range_and_error_codes_only_are_inf():
    from m4k_rt.control.guard import FrontSector
    sector = FrontSector(30.0)
    # code 0: "object possibly at 22 m" -- nothing within 5.6 m: free, like the sonar's no echo
    assert sector.minimum(-2.0, 0.01, 0.02, 5.6, [0] * 401) == INF
    # only error codes ahead (a black surface: low intensity): measured nothing, like a sonar
    # no echo off a curtain -- the other sensor is the witness
    assert sector.minimum(-2.0, 0.01, 0.02, 5.6, [2] * 401) == INF
    assert sector.minimum(-2.0, 0.01, 0.02, 5.6, [1] * 401) == INF
    assert sector.minimum(1.0, 0.01, 0.02, 5.6, [500] * 10) == INF   # sector not scanned
    with pytest.raises(GuardError, match='front_sector_deg'):
        FrontSector(0.0)


def test_front_sector_measures_from_the_front_face_not_the_laser():
    from m4k_rt.control.guard import front_offset, FrontSector
    robot = {'body': {'length': 0.45}, 'sensors': {'laser': {'pose': [0.0, 0, 0.2, 0, 0, 0]},
                                                   'sonar': {'pose': [0.225, 0, 0.1, 0, 0, 0]}}}
    assert front_offset(robot, 'laser') == pytest.approx(0.225)
    assert front_offset(robot, 'sonar') == 0.0
    assert front_offset({}, 'laser') == 0.0                      # no robot section: as measured
    sector = FrontSector(30.0, 0.225)
    inc = math.radians(1.0)
    ranges = [3000] * 241
    ranges[120] = 575                   # straight ahead, 0.575 m from the laser: 0.35 m gap
    assert sector.minimum(math.radians(-120.0), inc, 0.02, 5.6, ranges) == pytest.approx(0.35)
    ranges[120], ranges[130] = 3000, 600    # 10 deg off: 0.6 cos 10 - 0.225 ahead of the face
    assert sector.minimum(math.radians(-120.0), inc, 0.02, 5.6, ranges) == pytest.approx(
        0.6 * math.cos(math.radians(10)) - 0.225)
    ranges[130] = 100                   # inside the body's length: touching, 0
    assert sector.minimum(math.radians(-120.0), inc, 0.02, 5.6, ranges) == 0.0
