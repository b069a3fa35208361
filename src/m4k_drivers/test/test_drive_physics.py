"""The simulated drive on ground truth: braking within traction, slip, coasting (issue 28.1).

Every number here is the world's own truth (body speed, pose, wheel angles) on a fake clock;
the bounds come from the robot's parameters (``mu * g``, ``v^2 / (2 mu g)``), never from a run.
"""

import math

from fakeclock import FakeClock
import pytest

from m4k_drivers.drive import G, ROBOT_FIELDS, RobotParams
from m4k_drivers.world import LEFT, RIGHT, World, WorldConfig, WorldConfigError

FAR = WorldConfig.from_dict({'walls': {'rectangle': [-50, -50, 50, 50]}, 'obstacles': []}).walls
OPEN = WorldConfig(walls=FAR, obstacles=())
COAST = RobotParams(dynamic_brake_ohm=None)     # the enable's loss lets the motors float
MS = 1_000_000


def _world(robot=None):
    clock = FakeClock()
    cfg = OPEN if robot is None else WorldConfig(walls=FAR, obstacles=(), robot=robot)
    return World(cfg, clock=clock, t0_ns=0), clock


def _run(w, clock, seconds, each=None):
    """Advance ``seconds`` in 1 ms steps; ``each(world)`` after every step."""
    for _ in range(round(seconds * 1000)):
        clock.t += MS
        w.advance_to(clock.t)
        if each is not None:
            each(w)


def _drive_to(w, clock, speed):
    """Bring the robot to ``speed`` m/s on the volts its steady line needs; return the volts."""
    rob = w.robot
    lo, hi = 0.0, rob.supply_v
    for _ in range(50):                   # the volts of that steady speed (bisection)
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if rob.steady_wheel_speed(mid) * rob.wheel_radius_m < speed \
            else (lo, mid)
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, hi)
    _run(w, clock, 4.0)
    assert w.state().v == pytest.approx(speed, rel=0.01)
    return hi


def test_default_base_brakes_below_traction_and_states_its_figures():
    rob = RobotParams()
    assert rob.mu <= 0.7
    assert rob.braking_decel_mps2() < rob.mu * G
    assert rob.coast_decel_mps2 < rob.braking_decel_mps2()
    # Table 2's base: 2 m/s at full voltage on the floor, 30 kg, 12:1, 20.32 cm wheels
    assert rob.steady_wheel_speed(rob.supply_v) * rob.wheel_radius_m == pytest.approx(2.0)
    assert (rob.mass_kg, rob.gear_ratio, rob.wheel_diameter_m) == (30.0, 12.0, 0.2032)
    for name, fld in ROBOT_FIELDS.items():     # every parameter documented with its unit/source
        assert fld.description and getattr(rob, name) == fld.default


@pytest.mark.parametrize('v0', [0.5, 1.0, 2.0])
def test_zero_command_brakes_at_most_mu_g_and_stops_no_shorter_than_traction_allows(v0):
    w, clock = _world()
    _drive_to(w, clock, v0)
    x0, peak = w.state().pose.x, w.peak_decel
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, 0.0)
    decel = []
    _run(w, clock, 5.0, lambda w: decel.append(-w.state().accel))
    s = w.state()
    mu_g = w.robot.mu * G
    assert abs(s.v) < 1e-6
    assert max(decel) < mu_g and w.peak_decel < mu_g
    assert w.peak_decel >= peak
    assert s.pose.x - x0 >= v0 * v0 / (2.0 * mu_g)
    # and the peak is the current limit's braking the robot's parameters give
    assert max(decel) == pytest.approx(w.robot.braking_decel_mps2(), rel=0.02)


def test_braking_from_2_mps_with_a_strong_amplifier_is_limited_by_the_tyres():
    """Full reverse through a 20 A amplifier: the torque would give ~18 m/s^2; tyres slide."""
    w, clock = _world(RobotParams(amp_current_limit_a=20.0))
    _drive_to(w, clock, 2.0)
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, -w.robot.supply_v)
    decel, slipped = [], []
    _run(w, clock, 0.5, lambda w: (decel.append(-w.state().accel),
                                  slipped.append(max(map(abs, w.state().slip)))))
    assert max(decel) <= w.robot.mu * G + 1e-9
    assert max(slipped) > 0.1          # the tyres slid: the wheels turned the other way first


def test_hard_acceleration_slips_and_odometry_overstates_the_distance():
    w, clock = _world(RobotParams(amp_current_limit_a=20.0))
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, w.robot.supply_v)
    _run(w, clock, 1.0)
    s = w.state()
    odom = 0.5 * (s.wheel_angle[LEFT] + s.wheel_angle[RIGHT]) * w.robot.wheel_radius_m
    assert w.peak_slip > 0.1
    assert odom > s.pose.x + 0.05          # the encoders report rotation the body did not make
    assert w.peak_accel <= w.robot.mu * G + 1e-9


def test_gentle_drive_does_not_slip_and_odometry_matches_truth():
    w, clock = _world()
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, 6.0)
    _run(w, clock, 3.0)
    s = w.state()
    odom = 0.5 * (s.wheel_angle[LEFT] + s.wheel_angle[RIGHT]) * w.robot.wheel_radius_m
    assert w.peak_slip < 1e-6
    assert odom == pytest.approx(s.pose.x, abs=1e-6)


def test_enable_dropped_coasts_on_friction_alone():
    w, clock = _world(COAST)          # no dynamic brake wired
    volts = _drive_to(w, clock, 1.0)
    w.set_enable_until(clock.t)             # the heartbeat stops: the amplifiers float
    t0, x0 = clock.t, w.state().pose.x
    _run(w, clock, 0.5)
    s = w.state()
    coast = w.robot.coast_decel_mps2
    assert s.v == pytest.approx(1.0 - 0.5 * coast, abs=0.01)
    assert w.motor_voltage(LEFT) == volts          # the DACs still hold their word
    _run(w, clock, 1.0 / coast)
    s = w.state()
    assert s.v == 0.0
    # coasting distance v^2 / (2 a), up to one step of the sampled deceleration
    assert s.pose.x - x0 == pytest.approx(1.0 / (2.0 * coast), rel=0.02)
    assert (clock.t - t0) * 1e-9 >= 1.0 / coast


def test_estop_contact_cuts_the_enable_and_closing_it_drives_again():
    w, clock = _world(COAST)
    _drive_to(w, clock, 0.5)
    w.set_estop_open(True)
    assert not w.drive_enabled() and w.heartbeat_enabled()
    _run(w, clock, 0.1)
    assert w.state().accel == pytest.approx(-w.robot.coast_decel_mps2, rel=0.05)
    w.set_estop_open(False)
    _run(w, clock, 3.0)
    assert w.state().v == pytest.approx(0.5, rel=0.01)


def test_enable_dropped_with_the_dynamic_brake_brakes_on_the_back_emf():
    w, clock = _world()
    rob = w.robot
    assert rob.dynamic_brake_ohm is not None             # the default: the recommended wiring
    _drive_to(w, clock, 1.0)
    w.set_enable_until(clock.t)             # the heartbeat stops: the brake contact closes
    x0, t0 = w.state().pose.x, clock.t
    _run(w, clock, 0.001)
    s = w.state()
    # the armature current is the back-EMF over the armature and the brake resistor
    wm = s.wheel_speed[LEFT] * rob.gear_ratio
    assert w._drive.current[LEFT] == pytest.approx(
        -rob.ke * wm / (rob.motor_resistance_ohm + rob.dynamic_brake_ohm), rel=0.01)
    assert -s.accel == pytest.approx(rob.dynamic_brake_decel_mps2(s.v), rel=0.05)
    assert -s.accel > 3.0 * rob.coast_decel_mps2
    rest = _run_until_rest(w, clock, 5.0)
    assert rest is not None
    coast = 1.0 / (2.0 * rob.coast_decel_mps2)            # what coasting from 1 m/s takes
    assert w.state().pose.x - x0 < 0.5 * coast
    assert (clock.t - t0) * 1e-9 < 0.5 / rob.coast_decel_mps2


def _run_until_rest(w, clock, seconds):
    for k in range(round(seconds * 1000)):
        clock.t += MS
        w.now()
        if w.state().v == 0.0:
            return k * 1e-3
    return None


def test_a_wet_patch_under_one_wheel_slips_that_wheel_only():
    # full drive from rest with the left wheel on water: it spins, the right one grips
    cfg = WorldConfig.from_dict({'walls': {'rectangle': [-50, -50, 50, 50]}, 'obstacles': [],
                                 'floor': [{'rectangle': [-1.0, 0.0, 5.0, 1.0], 'mu': 0.05,
                                            'mu_kinetic': 0.04}]})
    clock = FakeClock()
    w = World(cfg, clock=clock, t0_ns=0)
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, w.robot.supply_v)
    _run(w, clock, 0.3)
    s = w.state()
    r = w.robot.wheel_radius_m
    assert abs(s.slip[LEFT]) > 0.1 and s.slip[RIGHT] == pytest.approx(0.0, abs=1e-3)
    assert s.wheel_speed[LEFT] * r > s.v + 0.1     # the left rim outruns the body
    assert s.w > 0.0                                # the gripping right wheel turns it left


def test_floor_patch_with_kinetic_above_static_is_refused_naming_the_field():
    with pytest.raises(WorldConfigError, match=r'world\.floor\[0\]\.mu_kinetic: must be <= mu'):
        WorldConfig.from_dict({'floor': [{'rectangle': [0, 0, 1, 1], 'mu': 0.2,
                                          'mu_kinetic': 0.3}]})


def test_a_weak_push_does_not_move_the_robot_dry_friction_holds():
    w, clock = _world()
    rob = w.robot
    below = 0.5 * rob.motor_resistance_ohm * rob.no_load_current_a
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, below)
    _run(w, clock, 1.0)
    assert w.state().v == 0.0 and w.state().wheel_speed == (0.0, 0.0)


@pytest.mark.parametrize('robot, match', [
    ({'mu': 0.0}, r'world\.robot\.mu: must be in \(0, 1\.5\]'),
    ({'mu': 0.5, 'mu_kinetic': 0.6}, r'world\.robot\.mu_kinetic: must be <= mu'),
    ({'gear_efficiency': 1.2}, r'world\.robot\.gear_efficiency: must be in \(0, 1\]'),
    ({'mass_kg': 'heavy'}, r"world\.robot\.mass_kg: expected a number, got 'heavy'"),
    ({'motor_resistance_ohm': 50.0}, r'world\.robot: the supply cannot overcome'),
])
def test_bad_robot_parameters_are_refused_naming_the_field(robot, match):
    with pytest.raises(WorldConfigError, match=match):
        WorldConfig.from_dict({'robot': robot})


def test_turning_in_place_keeps_the_centre_still():
    w, clock = _world()
    w.set_motor_voltage(LEFT, -6.0)
    w.set_motor_voltage(RIGHT, 6.0)
    _run(w, clock, 2.0)
    s = w.state()
    assert math.hypot(s.pose.x, s.pose.y) < 1e-9
    assert s.w > 0.5 and w.peak_slip < 1e-6


def test_a_drive_between_running_and_break_away_friction_keeps_a_wheel_turning_not_starting():
    # the drive train sticks harder at rest (breakaway_friction) than it runs: a drive between
    # the two holds a resting robot still and keeps a rolling one rolling (stick-slip at a creep)
    rob = RobotParams(drive_load_fraction=1.0)          # no casters: the wheels' friction only
    run_t = rob.friction_torque_nm + rob.rolling_force_n * rob.wheel_radius_m
    rest_t = rob.breakaway_torque_nm + rob.rolling_force_n * rob.wheel_radius_m
    assert rest_t > run_t
    # volts whose stall current gives a wheel torque halfway between the two
    per_volt = rob.gear_ratio * rob.gear_efficiency * rob.ke / rob.motor_resistance_ohm
    volts = 0.5 * (run_t + rest_t) / per_volt
    w, clock = _world(rob)
    for side in (LEFT, RIGHT):
        w.set_motor_voltage(side, volts)
    _run(w, clock, 1.0)
    assert w.state().v == 0.0                            # held: below break-away
    w2, clock2 = _world(rob)
    for side in (LEFT, RIGHT):
        w2.set_motor_voltage(side, 3.0 * volts)          # started above it...
    _run(w2, clock2, 0.5)
    for side in (LEFT, RIGHT):
        w2.set_motor_voltage(side, volts)                # ...then the same volts
    _run(w2, clock2, 2.0)
    assert w2.state().v > 0.0                            # rolls on: above running friction


def _ramp_world(grade_deg, robot=COAST):
    cfg = WorldConfig.from_dict({'walls': {'rectangle': [-50, -50, 50, 50]}, 'obstacles': [],
                                 'floor': [{'rectangle': [-40.0, -40.0, 40.0, 40.0], 'mu': 0.8,
                                            'grade_deg': grade_deg, 'downhill_deg': 0.0}]},
                                robot=robot)
    clock = FakeClock()
    return World(cfg, clock=clock, t0_ns=0), clock


def test_parked_on_a_ramp_the_robot_rolls_only_where_gravity_beats_its_friction():
    # enable off, no brake wired: gravity's pull m g sin(grade) against the drive train's
    # dry friction (break-away at rest, running once it rolls)
    rob = COAST
    hold = 2.0 * rob.breakaway_torque_nm / rob.wheel_radius_m + 2.0 * rob.rolling_force_n \
        + rob.caster_force_n
    held = math.degrees(math.asin(0.5 * hold / (rob.mass_kg * G)))
    rolls = math.degrees(math.asin(min(1.0, 2.0 * hold / (rob.mass_kg * G))))
    for grade, moves in ((held, False), (rolls, True)):
        w, clock = _ramp_world(grade)
        w.set_enable_until(0)
        _run(w, clock, 1.0)
        s = w.state()
        assert (s.pose.x > 0.01) == moves, (grade, s.pose.x)
        if moves:                      # downhill (+x), never faster than free fall along it
            assert 0.0 < s.v < G * math.sin(math.radians(grade)) * 1.0


def test_a_zero_word_brakes_less_downhill_by_the_slope_s_pull():
    # the drive brakes on its back-EMF at the amplifier's current limit; on a ramp down, the
    # ground truth's deceleration is less by g sin(grade) (4.8 deg: 0.82 m/s^2)
    peaks = []
    volts = None
    for grade in (0.0, 4.8):
        w, clock = _ramp_world(grade, RobotParams())
        if volts is None:
            volts = _drive_to(w, clock, 1.0)
        else:                          # the same volts: downhill it runs a little faster
            for side in (LEFT, RIGHT):
                w.set_motor_voltage(side, volts)
            _run(w, clock, 4.0)
        for side in (LEFT, RIGHT):
            w.set_motor_voltage(side, 0.0)
        v0 = w.state().v
        _run(w, clock, 0.1)
        peaks.append((v0 - w.state().v) / 0.1)
    assert peaks[0] - peaks[1] == pytest.approx(G * math.sin(math.radians(4.8)), rel=0.1)


def test_a_bad_grade_is_refused_naming_the_field():
    with pytest.raises(WorldConfigError, match=r'world\.floor\[0\]\.grade_deg'):
        WorldConfig.from_dict({'floor': [{'rectangle': [0, 0, 1, 1], 'mu': 0.5,
                                          'grade_deg': 30.0}]})
