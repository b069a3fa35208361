import math

import pytest

from m4k_drivers import config as dconfig
from m4k_drivers import registry
from m4k_drivers.drive import RobotParams
from m4k_drivers.motors import protocol as mp
from m4k_drivers.motors.handler import WheelCommand
from m4k_drivers.world import LEFT, Pose, RIGHT, World, WorldConfig, WorldConfigError


def test_default_world_matches_paper_layout():
    w = World(t0_ns=0, clock=lambda: 0)
    assert w.robot.track_width_m == 0.40
    assert w.robot.max_wheel_rad_s == pytest.approx(2.0 / 0.1016)
    # the triangle's flat face is 1.5 m ahead of the start
    assert w.raycast((0.0, 0.0), 0.0, 10.0) == pytest.approx(1.5)
    assert w.raycast((0.0, 0.0), math.pi, 10.0) == pytest.approx(0.8)
    assert w.raycast((0.0, 0.0), math.pi / 2, 1.0) == math.inf        # wall at 1.5 > max


def test_cone_cast_sees_obstacle_off_axis():
    w = World(t0_ns=0, clock=lambda: 0)
    # aim 20 deg left: the centre ray misses the 0.5 m wide face, a 30 deg cone still sees it
    assert w.raycast((0.0, 0.0), math.radians(20), 1.55) == math.inf
    assert w.cone_cast((0.0, 0.0), math.radians(20), math.radians(15), 1.6) < 1.6


def test_spin_in_place_integrates_exact_arc(fake_clock):
    t = fake_clock
    # all the weight on the drive wheels: spinning in place then meets the rolling resistance
    # of a straight run, which steady_wheel_speed describes (the casters' share resists the
    # body's forward motion only)
    w = World(WorldConfig(obstacles=(), robot=RobotParams(drive_load_fraction=1.0)), clock=t,
              t0_ns=0)
    w.set_motor_voltage(LEFT, -6.0)
    w.set_motor_voltage(RIGHT, 6.0)
    t.t = 3_000_000_000
    w.advance_to(t.t)
    s = w.state()
    assert abs(s.pose.x) < 1e-9 and abs(s.pose.y) < 1e-9
    # steady wheel speed on the motor's line at 6 V (a quarter of the supply, less what the
    # friction's current takes: the old lag model's exact 6/24 of max was frictionless)
    ws = w.robot.steady_wheel_speed(6.0)
    assert 0.95 * 0.25 * w.robot.max_wheel_rad_s < ws < 0.25 * w.robot.max_wheel_rad_s
    assert s.w == pytest.approx(2 * 0.1016 * ws / 0.40, rel=1e-3)
    assert s.wheel_angle[LEFT] == pytest.approx(-s.wheel_angle[RIGHT])


def test_drive_into_obstacle_stops_and_counts_collision(fake_clock):
    t = fake_clock
    w = World(clock=t, t0_ns=0)
    w.set_motor_voltage(LEFT, 6.0)
    w.set_motor_voltage(RIGHT, 6.0)
    t.t = 20_000_000_000
    w.advance_to(t.t)
    s = w.state()
    assert s.in_contact and s.collisions == 1 and s.v == 0.0
    # the front of the body (x + 0.225) stopped at the obstacle face at 1.5 m
    assert 1.5 - 0.225 - 0.01 < s.pose.x < 1.5 - 0.225
    w.set_motor_voltage(LEFT, -6.0)
    w.set_motor_voltage(RIGHT, -6.0)
    t.t += 1_000_000_000
    w.advance_to(t.t)
    assert not w.state().in_contact and w.state().collisions == 1


def test_world_is_deterministic_for_a_seed():
    a = World(WorldConfig(seed=7), t0_ns=0, clock=lambda: 0).rng('imu').normal(size=3)
    b = World(WorldConfig(seed=7), t0_ns=0, clock=lambda: 0).rng('imu').normal(size=3)
    c = World(WorldConfig(seed=8), t0_ns=0, clock=lambda: 0).rng('imu').normal(size=3)
    assert list(a) == list(b) and list(a) != list(c)


def test_start_inside_obstacle_is_a_config_error():
    with pytest.raises(WorldConfigError, match='world.start'):
        World(WorldConfig(start=Pose(1.6, 0.0, 0.0)), t0_ns=0, clock=lambda: 0)


@pytest.mark.parametrize('section, match', [
    ({'walls': {'rectangle': [0, 0, 1]}},
     r'world\.walls\.rectangle: expected \[xmin, ymin, xmax, ymax\] \(4 finite numbers\), got'),
    ({'walls': [[0, 0, 1, 'x']]},
     r"world\.walls\[0\]: expected \[x1, y1, x2, y2\] \(4 finite numbers\), got \[0, 0, 1, 'x'\]"),
    ({'obstacles': [[[0, 0], [1, 1]]]}, r'world\.obstacles\[0\]: expected a polygon'),
    ({'start': [0, 0]}, r'world\.start: expected a list of 3'),
    ({'robot': {'track_width_m': -1}}, r'world\.robot\.track_width_m: must be > 0'),
    ({'robot': {'wheels': 3}},
     r'world\.robot\.wheels: unknown key \(allowed: amp_current_limit_a, '),
    ({'seed': 1.5}, r'world\.seed: expected an integer'),
    ({'gravity': 9.8},
     r'world\.gravity: unknown key \(allowed: events, faults, floor, obstacles, robot, seed, '),
])
def test_world_config_errors_name_the_field(section, match):
    with pytest.raises(WorldConfigError, match=match):
        WorldConfig.from_dict(section)


def test_drive_straight_one_metre_sensors_agree(m4k_runtime_dir, fake_clock):
    """Drive 1 m through DAC frames on the sim-bus; encoders, IMU yaw, ray cast, sonar agree.

    Motor and IMU go through the sim-bus to a SimRobot on a fake clock; the sonar's trigger
    pulse is timed by a busy wait on the real clock, so it runs on the same world in-process.
    """
    from m4k_drivers.sim_robot import SimRobot
    from m4k_rt.channel import ensure_runtime_dir
    clock = fake_clock
    doc = {'devices': {'motor': {'backend': 'sim'}, 'imu': {'backend': 'sim'}},
           'world': {'walls': {'rectangle': [-0.8, -1.5, 4.2, 1.5]}, 'obstacles': [],
                     'seed': 3}}
    cfg = dconfig.validate(doc)
    rd = ensure_runtime_dir(m4k_runtime_dir)
    robot = SimRobot(cfg, rd, clock=clock, sleep=clock.sleep).start()
    ctx = registry.BuildContext(clock=clock, sleep=clock.sleep, runtime_dir=rd)
    motor = registry.create('motor', cfg.devices['motor'], ctx)
    imu = registry.create('imu', cfg.devices['imu'], ctx)
    try:
        _drive_and_compare(robot, motor, imu, clock)
    finally:
        for h in (motor, imu):
            h.shutdown()
        robot.close()
    world = robot.world
    assert world.motor_voltage(LEFT) == 0.0 and world.motor_voltage(RIGHT) == 0.0


def _drive_and_compare(robot, motor, imu, clock):
    from m4k_drivers.sonar import SonarHandler
    from m4k_drivers.sonar.sim import open_sim_sonar
    world = robot.world
    sonar = SonarHandler(lambda: open_sim_sonar(world, sleep=clock.sleep))
    for h in (motor, imu, sonar):
        h.configure()
        h.activate()
    r = world.robot.wheel_radius_m
    start = motor.read().value

    def travelled(enc):
        turned = (enc.left_angle - start.left_angle) + (enc.right_angle - start.right_angle)
        return turned / 2 * r

    code = mp.command_to_code(0.125)             # 0.25 m/s
    dist = 0.0
    for _ in range(1000):
        clock.t += 10_000_000
        motor.write(WheelCommand(code, code, 1))
        enc = motor.read().value
        dist = travelled(enc)
        if dist >= 1.0:
            break
    for _ in range(60):                           # brake and settle (motor lag 80 ms)
        clock.t += 10_000_000
        motor.write(WheelCommand(512, 512, 1))
        enc = motor.read().value
    dist = travelled(enc)
    pose = world.pose()
    count_m = 2 * math.pi * r / 4096
    # encoders vs true pose: 0.5 LSB noise per reading, floor quantisation -> within 3 counts
    assert 1.0 <= dist < 1.05
    assert pose.x == pytest.approx(dist, abs=3 * count_m)
    # IMU yaw ~ 0: orientation noise sd 0.00214 rad (4 sd) plus one 16-bit LSB
    yaw = imu.read().value.rpy[2]
    assert abs(yaw) < 4 * 0.002143 + math.radians(180 / 32767)
    # ray cast to the front wall from where the encoders say we are
    ahead = world.raycast((pose.x, pose.y), yaw, 10.0)
    assert ahead == pytest.approx(4.2 - dist, abs=3 * count_m + 4.2 * abs(yaw) ** 2)
    # sonar (0.225 m ahead of base_link) through the edge-level sim: noise sd 3 mm
    s = sonar.read().value
    assert s.status == 0
    assert s.range_m == pytest.approx(4.2 - dist - 0.225, abs=4 * 0.003 + 3 * count_m)
    sonar.shutdown()


def test_wheel_angle_between_steps_is_the_angle_at_that_time(fake_clock):
    # 1 ms steps: at 2.5 ms the stepped state is from 2 ms; a read at 2.5 ms must not see it.
    t = fake_clock
    w = World(WorldConfig(obstacles=()), clock=t, t0_ns=0)
    fine = World(WorldConfig(obstacles=(), step_s=1e-5), clock=t, t0_ns=0)
    for world in (w, fine):
        world.set_motor_voltage(LEFT, 12.0)
        world.set_motor_voltage(RIGHT, 12.0)
    t.t = 200_000_000
    fine.advance_to(t.t)
    base, fine_base = w.wheel_angle_at(LEFT), fine.state().wheel_angle[LEFT]
    t.t = 200_500_000
    fine.advance_to(t.t)
    angle = w.wheel_angle_at(LEFT)
    stepped = w.state()
    assert stepped.t_ns == 200_000_000 and stepped.wheel_angle[LEFT] == base
    # It moved on over the 0.5 ms (about 1.7e-3 rad at 3.3 rad/s: the amplifier's current
    # limit accelerates the base at ~1.7 m/s^2), as a world stepped 100x finer did over the
    # same 0.5 ms (the speed changes by 0.5 % per ms, hence 1 %).
    assert angle - base == pytest.approx(fine.state().wheel_angle[LEFT] - fine_base, rel=0.01)
    assert angle - base > 1.5e-3
    assert w.wheel_angle_at(RIGHT, 200_500_000) == pytest.approx(w.wheel_angle_at(LEFT))
    with pytest.raises(ValueError, match='side must be'):
        w.wheel_angle_at(2)


def test_world_report_failure_is_logged_once_and_recovery_once(m4k_runtime_dir, tmp_path,
                                                               caplog):
    """The report is rewritten every 100 ms: a missing directory must not flood the log."""
    import json
    import logging

    from m4k_drivers.sim_robot import SimRobot
    from m4k_rt.channel import ensure_runtime_dir
    cfg = dconfig.validate({'devices': {'imu': {'backend': 'sim'}}})
    rd = ensure_runtime_dir(m4k_runtime_dir)
    where = tmp_path / 'gone'
    robot = SimRobot(cfg, rd, str(where / 'world.json'))   # not started: writes by hand
    try:
        with caplog.at_level(logging.INFO, logger='m4k_drivers.sim_robot'):
            for _ in range(5):
                robot.write_report()
            failures = [r for r in caplog.records if 'world report' in r.getMessage()]
            assert len(failures) == 1 and failures[0].levelno == logging.WARNING
            assert 'No such file or directory' in failures[0].getMessage()
            where.mkdir()
            robot.write_report()
            robot.write_report()
    finally:
        robot.close()
    msgs = [r.getMessage() for r in caplog.records if 'world report' in r.getMessage()]
    assert len(msgs) == 2 and msgs[1].endswith('written again')
    assert len(json.loads((where / 'world.json').read_text())['pose']) == 3


def test_world_scene_and_fault_errors_are_config_errors():
    # One configuration error type (m4k_rt.schema.ConfigError), a subclass per source.
    from m4k_drivers.faults import FaultError
    from m4k_drivers.scene import SceneError
    from m4k_rt.schema import ConfigError
    assert all(issubclass(c, ConfigError) for c in (WorldConfigError, FaultError, SceneError))
    with pytest.raises(ConfigError) as info:
        WorldConfig.from_dict({'faults': [{'at_s': 1, 'kind': 'estop', 'until_s': 0.5}]})
    assert info.value.path == 'world.faults[0].until_s'


def test_a_moment_the_world_has_stepped_past_is_answered_with_the_angle_of_then(fake_clock):
    # A read handled late (a simulator short of CPU) asks for the moment it started: the
    # world has moved on, and answers from its kept past, as a world that stopped there would.
    t = fake_clock
    w = World(WorldConfig(obstacles=()), clock=t, t0_ns=0)
    still = World(WorldConfig(obstacles=()), clock=t, t0_ns=0)
    for world in (w, still):
        world.set_motor_voltage(LEFT, 12.0)
        world.set_motor_voltage(RIGHT, -6.0)
    t.t = 300_250_000
    then = [still.wheel_angle_at(side) for side in (LEFT, RIGHT)]
    t.t = 380_000_000          # 80 ms later the world has stepped on ...
    assert w.wheel_angle_at(LEFT) - then[LEFT] > 0.1
    for side in (LEFT, RIGHT):  # ... and still says where each wheel was at 300.25 ms
        assert w.wheel_angle_at(side, 300_250_000) == pytest.approx(then[side], abs=1e-9)
    # older than the kept past (WHEEL_HISTORY_S): the oldest kept step, never a later one
    t.t = 2_000_000_000
    w.now()
    oldest = w.wheel_angle_at(LEFT, 0)
    assert oldest == pytest.approx(w.wheel_angle_at(LEFT, 1_500_000_000), abs=1e-9)
    assert oldest < w.wheel_angle_at(LEFT, 1_700_000_000)
