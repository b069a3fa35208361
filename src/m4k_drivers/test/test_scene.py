"""The simulated scene: surfaces per sensor, heights, moving obstacles, unplug events, truth."""

import errno
import math

from fakeclock import FakeClock
import pytest

from m4k_drivers import config as dconfig
from m4k_drivers.lrf.sim import LOW_LIGHT_CODE, UrgSim
from m4k_drivers.sonar import protocol as p
from m4k_drivers.world import LEFT, Pose, RIGHT, World, WorldConfig, WorldConfigError

PANEL = [[2.0, -0.6], [2.05, -0.6], [2.05, 0.6], [2.0, 0.6]]
HALL = [[8.0, -3.0, 8.0, 3.0]]


def _world(obstacles, walls=HALL, **extra):
    return World(WorldConfig.from_dict({'walls': walls, 'obstacles': obstacles, **extra}),
                 clock=FakeClock(), t0_ns=0)


@pytest.mark.parametrize('surface, laser, sonar', [
    ('normal', 2.0, 2.0),
    ('soft', 2.0, math.inf),           # curtain: the laser sees it, no echo comes back
    ('glass', 8.0, 2.0),               # the laser sees the wall behind, the sonar the pane
    ('black', 2.0, 2.0),               # the laser's ray ends there (flagged: error code)
])
def test_each_sensor_sees_what_the_surface_lets_it(surface, laser, sonar):
    w = _world([{'polygon': PANEL, 'surface': surface}])
    dist, black = w.laser_cast((0.0, 0.0), [0.0], 5.6 if laser < 5.6 else 10.0, 0.3)
    assert dist[0] == pytest.approx(laser)
    assert bool(black[0]) == (surface == 'black')
    assert w.sonar_cast((0.0, 0.0), 0.0, 0.13, 4.5, 0.2) == pytest.approx(sonar)


def _leg(x, y, w=0.03):
    return [[x, y - w / 2], [x + w, y - w / 2], [x + w, y + w / 2], [x, y + w / 2]]


@pytest.mark.parametrize('bearing_deg', [0.0, 0.94, 2.8, -4.7, 6.6, -7.4])
@pytest.mark.parametrize('dist', [0.9, 2.0, 3.5])
def test_the_sonar_hears_a_thin_leg_anywhere_in_its_cone(dist, bearing_deg):
    """A sonar's beam is a cone, not rays: the US-100 hears a 3 cm chair leg wherever in its
    15 deg cone the leg stands (the nearest reflector's range). A fan of nine rays, 1.9 deg
    apart (6.5 cm at 2 m), missed a leg between two of them: on the stack a black leg at the
    front face's edge (the laser's error code: the sonar alone) went unheard for 0.6 s at
    ~2 m and the guard tripped 0.37 m past its stop line."""
    a = math.radians(bearing_deg)
    x, y = dist * math.cos(a), dist * math.sin(a)
    w = _world([{'polygon': _leg(x, y)}], walls=[[12.0, -6.0, 12.0, 6.0]])
    assert w.sonar_cast((0.0, 0.0), 0.0, math.radians(7.5), 4.5, 0.2) == pytest.approx(
        math.hypot(x, y), abs=0.016)


def test_the_sonar_does_not_hear_a_leg_just_outside_its_cone():
    a = math.radians(7.5 + 1.5)
    w = _world([{'polygon': _leg(2.0 * math.cos(a), 2.0 * math.sin(a), 0.01)}],
               walls=[[12.0, -6.0, 12.0, 6.0]])
    assert w.sonar_cast((0.0, 0.0), 0.0, math.radians(7.5), 4.5, 0.2) == math.inf


def test_a_curtain_hides_the_wall_behind_it_from_the_sonar_but_not_a_leg_before_it():
    curtain = {'polygon': PANEL, 'surface': 'soft'}
    w = _world([curtain], walls=[[3.0, -3.0, 3.0, 3.0]])
    assert w.sonar_cast((0.0, 0.0), 0.0, 0.13, 4.5, 0.2) == math.inf
    w = _world([curtain, {'polygon': _leg(1.2, 0.1)}], walls=[[3.0, -3.0, 3.0, 3.0]])
    assert w.sonar_cast((0.0, 0.0), 0.0, 0.13, 4.5, 0.2) == pytest.approx(
        math.hypot(1.2, 0.085), abs=0.005)


def test_a_low_obstacle_is_under_the_laser_plane_but_in_the_sonar_beam_and_the_body():
    w = _world([{'polygon': PANEL, 'height': 0.25}])
    assert w.laser_cast((0.0, 0.0), [0.0], 10.0, 0.3)[0][0] == pytest.approx(8.0)
    assert w.sonar_cast((0.0, 0.0), 0.0, 0.13, 4.5, 0.2) == pytest.approx(2.0)
    assert w.collides(Pose(1.9, 0.0, 0.0))               # the body still hits it


def test_urg_reports_low_intensity_code_on_a_black_panel_and_code_0_through_glass():
    for surface, code in (('black', LOW_LIGHT_CODE), ('glass', 0)):
        w = _world([{'polygon': PANEL, 'surface': surface}], walls=[[9.0, -3, 9.0, 3]])
        urg = UrgSim(w, height=0.3)
        ahead = int(urg.spec.afrt)
        out = urg.measure(ahead, ahead)
        assert out[0] == code          # glass: the wall behind is 9 m > 5.6 m: code 0


def test_moving_obstacle_starts_on_the_robots_true_distance_and_follows_its_waypoints(fake_clock):
    clock = fake_clock
    person = {'polygon': [[3.0, 2.0], [3.2, 2.0], [3.2, 2.4], [3.0, 2.4]],
              'path': {'start': {'travelled': 0.2}, 'waypoints': [[0, 0, 0], [2.0, 0, -2.0]]}}
    w = World(WorldConfig.from_dict({'walls': HALL, 'obstacles': [person]}), clock=clock,
              t0_ns=0)
    clock.t = 1_000_000_000
    w.advance_to(clock.t)
    assert w.obstacle_offsets() == [(0.0, 0.0)]        # robot at rest: the person waits
    w.set_motor_voltage(LEFT, 6.0)
    w.set_motor_voltage(RIGHT, 6.0)
    while w.travelled < 0.2:
        clock.t += 10_000_000
        w.advance_to(clock.t)
    t_start = clock.t
    clock.t = t_start + 1_000_000_000
    w.advance_to(clock.t)
    dx, dy = w.obstacle_offsets()[0]
    assert dx == 0.0 and dy == pytest.approx(-1.0, abs=0.02)      # 1 m/s for 1 s
    clock.t = t_start + 5_000_000_000
    w.set_motor_voltage(LEFT, 0.0)
    w.set_motor_voltage(RIGHT, 0.0)
    w.advance_to(clock.t)
    assert w.obstacle_offsets()[0][1] == pytest.approx(-2.0)     # held after the last point


def test_a_person_walking_into_the_robot_at_rest_is_a_contact(fake_clock):
    clock = fake_clock
    person = {'polygon': [[1.0, -0.2], [1.2, -0.2], [1.2, 0.2], [1.0, 0.2]],
              'path': {'start': {'after': 0.0}, 'waypoints': [[0, 0, 0], [1.0, -1.0, 0]]}}
    w = World(WorldConfig.from_dict({'walls': HALL, 'obstacles': [person]}), clock=clock,
              t0_ns=0)
    w.set_motor_voltage(LEFT, 3.0)          # a nudge so the motion clock starts
    w.set_motor_voltage(RIGHT, 3.0)
    while w.travelled < 0.01:
        clock.t += 1_000_000
        w.advance_to(clock.t)
    w.set_motor_voltage(LEFT, 0.0)
    w.set_motor_voltage(RIGHT, 0.0)
    clock.t += 3_000_000_000
    w.advance_to(clock.t)
    assert w.collisions == 1 and w.min_clearance == 0.0


def test_clearance_is_the_gap_between_footprint_and_nearest_surface():
    w = _world([{'polygon': PANEL}])
    assert w.clearance(Pose(0.0, 0.0, 0.0)) == pytest.approx(2.0 - 0.225)
    assert w.front_clearance(Pose(0.0, 0.0, 0.0)) == pytest.approx(2.0 - 0.225)
    assert w.min_clearance == pytest.approx(2.0 - 0.225)


@pytest.mark.parametrize('section, message', [
    ({'obstacles': [{'polygon': PANEL, 'surface': 'mirror'}]}, r'obstacles\[0\]\.surface'),
    ({'obstacles': [{'polygon': PANEL, 'height': 0}]}, r'obstacles\[0\]\.height: must be > 0'),
    ({'obstacles': [{'polygon': PANEL, 'path': {'waypoints': [[1, 0, 0], [0, 1, 1]]}}]},
     r'obstacles\[0\]\.path\.waypoints: times must'),
    ({'obstacles': [{'polygon': PANEL, 'path': {'start': {'when': 1}, 'waypoints': [[0, 0, 0]]}}]},
     r'obstacles\[0\]\.path\.start'),
    ({'events': [{'at': {'travelled': 1}, 'unplug': 'motor'}]}, r'events\[0\]\.unplug'),
    ({'events': [{'unplug': 'sonar'}]}, r'events\[0\]'),
])
def test_bad_scene_entries_name_the_field(section, message):
    with pytest.raises(WorldConfigError, match=message):
        WorldConfig.from_dict(section)


def test_unplug_events_make_the_devices_do_what_unplugged_hardware_does(m4k_runtime_dir,
                                                                         fake_clock):
    from m4k_drivers.sim_robot import SimRobot
    from m4k_rt.channel import ensure_runtime_dir
    clock = fake_clock
    doc = {'devices': {'motor': {'backend': 'sim'}, 'imu': {'backend': 'sim'},
                       'sonar': {'backend': 'sim', 'mount': [0.225, 0.0, 0.0]}},
           'world': {'walls': HALL, 'obstacles': [],
                     'events': [{'at': {'travelled': 0.05}, 'unplug': 'sonar'},
                                {'at': {'travelled': 0.05}, 'unplug': 'imu'}]}}
    cfg = dconfig.validate(doc)
    robot = SimRobot(cfg, ensure_runtime_dir(m4k_runtime_dir), clock=clock, sleep=clock.sleep)
    try:
        bus = next(iter(robot.i2c.values()))
        addr = next(iter(bus.devices))
        bus.read_burst(addr, 0, 1)                         # answers before
        robot.world.set_enable_until(None)                 # no heartbeat in this test
        robot.world.set_motor_voltage(LEFT, 6.0)
        robot.world.set_motor_voltage(RIGHT, 6.0)
        clock.t = 1_000_000_000
        robot.apply_events()
        assert {e['unplug'] for e in robot.events} == {'sonar', 'imu'}
        assert all(e['applied'] for e in robot.events)
        assert robot.sonar_trigger.dead
        with pytest.raises(OSError) as exc:
            bus.read_burst(addr, 0, 1)
        assert exc.value.errno == errno.EREMOTEIO
        truth = robot.truth()
        assert truth['travelled'] > 0.05
        assert sorted(e['unplug'] for e in truth['events']) == ['imu', 'sonar']
    finally:
        robot.close()


def test_no_echo_pulse_of_the_sim_is_nothing_in_range():
    from m4k_drivers.sonar.sim import NO_ECHO_PULSE_S
    assert p.pulse_to_range(NO_ECHO_PULSE_S).status == p.STATUS_NO_ECHO


def test_the_world_stamps_when_the_robot_came_to_rest(fake_clock):
    clock = fake_clock
    w = World(WorldConfig.from_dict({'walls': HALL, 'obstacles': []}), clock=clock, t0_ns=0)
    assert w.rest_since_ns == 0
    w.set_motor_voltage(LEFT, 6.0)
    w.set_motor_voltage(RIGHT, 6.0)
    clock.t = 1_000_000_000
    w.advance_to(clock.t)
    assert w.rest_since_ns is None
    w.set_motor_voltage(LEFT, 0.0)
    w.set_motor_voltage(RIGHT, 0.0)
    clock.t = 3_000_000_000
    w.advance_to(clock.t)
    t_rest = w.rest_since_ns
    assert t_rest is not None and 1_000_000_000 < t_rest < 3_000_000_000
    clock.t = 4_000_000_000
    w.advance_to(clock.t)
    assert w.rest_since_ns == t_rest        # still at rest since then


def test_the_wheels_are_part_of_the_footprint_and_in_line_edges_far_apart_do_not_touch():
    # The drive wheels stand outside the 0.28 m body (outer faces 0.225 m off the centre
    # line): a leg 0.21 m off the line clears the body and meets the wheel. A leg whose side
    # is in line with the wheel's outer face, metres ahead, is no contact (collinear edges).
    from m4k_drivers.world import Pose, World, WorldConfig
    leg = [[3.0, 0.195], [3.03, 0.195], [3.03, 0.225], [3.0, 0.225]]
    w = World(WorldConfig.from_dict({'walls': {'rectangle': [-1.0, -3.0, 8.0, 3.0]},
                                     'obstacles': [leg]}), clock=lambda: 0, t0_ns=0)
    assert not w.collides(Pose(0.0, 0.0, 0.0))
    assert w.collides(Pose(3.0, 0.0, 0.0))              # the left wheel at the leg
    assert not w.collides(Pose(3.0, -0.1, 0.0))         # shifted right: the wheel clears it
    # beside the leg the body's side passes it 5.5 cm away; 2 cm before the wheel meets it,
    # the wheel's front is the nearest part
    assert w.clearance(Pose(2.8, 0.0, 0.0)) == pytest.approx(0.195 - 0.14, abs=1e-6)
    assert w.clearance(Pose(2.8784, 0.0, 0.0)) == pytest.approx(0.02, abs=1e-6)
