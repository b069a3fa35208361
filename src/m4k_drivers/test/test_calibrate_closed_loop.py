"""The calibrated configuration drives the robot as built; the configured one does not.

Everything in simulated time (a fake clock that the runs' waits advance), so it is
deterministic: ``calibrate``'s steps (:func:`m4k_drivers.calibrate.cli.identify`) run against a
world whose robot differs from ``config/control.yaml`` (radius -3 %, track +5 %, amplifier
zero errors, a dead band), the person measuring reads the world's ground truth; then the RT
base controller (``m4k_rt.control``: limiter, kinematics, wheel-speed PI, odometry) drives that
same robot through the motor handler, once with the configuration as shipped and once with the
calibrated overlay, and the ground truth says which one does what it is told.
"""

import argparse
import io
import math

from fakeclock import FakeClock, SteppingStop
import pytest

from m4k_drivers.calibrate import cli, runs
from m4k_drivers.drive import DriveState, step_drive
from m4k_drivers.motors.handler import MotorHandler, WheelCommand
from m4k_drivers.motors.sim import open_sim_bus
from m4k_drivers.world import World, WorldConfig
from m4k_rt.config import deep_merge, load_layered, shipped_period_s
from m4k_rt.control.base import BaseController
from m4k_rt.control.params import control_params

PERIOD_S = shipped_period_s('actuator')   # the actuator task's, as shipped

# drive_load_fraction 1.0 (no caster load): with the casters' share (the simulator's default
# 0.5 since issue 39) calibrate's sweep puts both zero trims 2 codes (0.09 V) low -- a gap of
# the sweep's fit with a caster-loaded body, reported, not yet fixed.
AS_BUILT = {'wheel_diameter_m': 0.2032 * 0.97, 'track_width_m': 0.42, 'top_speed_mps': 2.1,
            'amp_offset_left_v': 0.3, 'amp_offset_right_v': -1.2, 'deadband_v': 0.9,
            'drive_load_fraction': 1.0}


def _robot(trim=(0, 0)):
    clock = FakeClock()
    world = World(WorldConfig.from_dict({'robot': AS_BUILT, 'obstacles': [], 'seed': 7,
                                         'walls': {'rectangle': [-20, -20, 20, 20]}}),
                  clock=clock, t0_ns=0)
    handler = MotorHandler(lambda: open_sim_bus(world), clock=clock, dac_zero_trim=trim,
                           period_s=PERIOD_S)
    return world, handler, clock


class TruthOperator(cli.Operator):
    """The person with the tape measure: marks at every confirmation, measures on the truth."""

    def __init__(self, world):
        super().__init__(io.StringIO(), io.StringIO(), assume_yes=True)
        self.world = world
        self.mark = None

    def confirm(self, text):
        self.mark = self.world.pose()

    def number(self, text, default):
        end = self.world.pose()
        if 'distance' in text:
            return math.hypot(end.x - self.mark.x, end.y - self.mark.y)
        turned = math.atan2(math.sin(end.yaw - self.mark.yaw), math.cos(end.yaw - self.mark.yaw))
        plan = 2 * math.pi if 'counter-clockwise' in text else -2 * math.pi
        return abs(math.degrees(turned + 2 * math.pi * round((plan - turned) / (2 * math.pi))))


@pytest.fixture(scope='module')
def calibrated():
    """Run calibrate's steps on the as-built robot; return (shipped control, calibrated)."""
    shipped = load_layered()['control']
    world, handler, clock = _robot()
    args = argparse.Namespace(hold=1.5, max_speed=0.25, levels=5, settle=0.6, measure=0.6,
                              speed=0.15, distance=1.0, turns=1, lam=0.15, brake_speed=0.25,
                              brake_settle=1.5)
    res = {}
    op = TruthOperator(world)
    with runs.MotorRig(handler, SteppingStop(clock), clock=clock.seconds) as rig:
        cli.identify(rig, list(cli.STEPS), args, control_params(shipped), op, res)
    overlay = cli.overlay_doc(res)
    return shipped, deep_merge(shipped, overlay['control']), \
        tuple(overlay['devices']['motor']['dac_zero_trim'])


def _drive(control, trim, v_cmd, w_cmd, seconds=4.0):
    """Drive the as-built robot with the RT controller; return truth and odometry at the end."""
    world, handler, clock = _robot(trim)
    ctl = BaseController(control_params(control), 0.01)
    handler.configure()
    handler.activate()
    try:
        while clock.t < seconds * 1e9:
            r = handler.read()
            ctl.encoders(r.value.left_angle, r.value.right_angle, r.value.t_ns, clock.t)
            ctl.command(v_cmd, w_cmd, clock.t)
            ctl.step(clock.t)
            handler.write(WheelCommand(ctl.left_code, ctl.right_code, ctl.enable))
            clock.t += 10_000_000
    finally:
        handler.shutdown()
    return world.state(), ctl.odom


def test_calibrated_values_are_the_robot_as_built(calibrated):
    shipped, cal, trim = calibrated
    assert cal['wheel_radius'] == pytest.approx(AS_BUILT['wheel_diameter_m'] / 2, rel=0.01)
    assert cal['track_width'] == pytest.approx(AS_BUILT['track_width_m'], rel=0.01)
    # full_scale_wheel_speed is the feed-forward gain: the slope of the wheel speed against
    # the command, times the full scale (the PI integrator covers the dead band). With the
    # drive physics that line is affine -- the amplifier's dead band and offset and the
    # current the friction and rolling resistance take shift it -- so it is not the top speed
    # (at full armature voltage) over the radius: the truth is the simulator's own steady
    # speed line, its slope between half and full scale.
    rob = _robot()[0].robot
    full_v = rob.supply_v
    for side in (0, 1):
        w_half, w_full = (rob.steady_wheel_speed(v, side) for v in (full_v / 2, full_v))
        true_full = (w_full - w_half) / (full_v / 2) * full_v
        assert cal['full_scale_wheel_speed'] == pytest.approx(true_full, rel=0.01)
    # ... which is more than the top speed over the radius (the line does not pass through 0).
    assert true_full > AS_BUILT['top_speed_mps'] / (AS_BUILT['wheel_diameter_m'] / 2)
    assert trim == (round(-0.3 / 24 * 511), round(1.2 / 24 * 511))


def _straight_step_lag(rob, v1=3.0, v2=4.0, dt=1e-3):
    """Time the simulated drive itself: a small straight-line step of both armatures, v1 -> v2.

    The gap between the wheel angle and its final asymptote, over the speed step, is the lag of
    a first-order response (the area above it); below the current limit the drive is one.
    """
    st = DriveState()
    volts = tuple(v1 - rob.amp_offset_v(side) for side in (0, 1))
    for _ in range(3000):
        step_drive(rob, st, volts, True, dt)
    w1 = st.wheel[0]
    volts = tuple(v2 - rob.amp_offset_v(side) for side in (0, 1))
    speeds = []
    for _ in range(3000):
        step_drive(rob, st, volts, True, dt)
        speeds.append(st.wheel[0])
        assert abs(st.current[0]) < rob.amp_current_limit_a      # linear: no current limit
    w2 = speeds[-1]
    return sum(w2 - w for w in speeds) * dt / (w2 - w1)


def test_calibrated_pi_follows_the_robots_lag(calibrated):
    shipped, cal, trim = calibrated
    rob = _robot()[0].robot
    # The truth is the simulator's: the straight-line time constant of its drive below the
    # current limit, which drive.py derives from its physical parameters (motor_tau_s) and
    # which a small step on the simulated drive shows. It is the lag the PI zero must cancel
    # (kp / ki = tau, lambda tuning); the in-place turn's lag (the wheels move the yaw inertia
    # only, about half of it) is not.
    assert _straight_step_lag(rob) == pytest.approx(rob.motor_tau_s, rel=0.01)
    assert cal['pi']['kp'] / cal['pi']['ki'] == pytest.approx(rob.motor_tau_s, rel=0.05)


def _wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


@pytest.mark.parametrize('v_cmd, w_cmd', [(0.4, 0.0), (0.0, 1.0)])
def test_the_calibrated_robot_does_what_it_is_told_and_knows_where_it_is(calibrated, v_cmd,
                                                                         w_cmd):
    shipped, cal, trim = calibrated
    r_true = AS_BUILT['wheel_diameter_m'] / 2
    errors = {}
    for name, control, t in (('shipped', shipped, (0, 0)), ('calibrated', cal, trim)):
        st, odom = _drive(control, t, v_cmd, w_cmd)
        # Steady state (the limiters ramped long ago): the robot's speed against the command,
        # and where odometry thinks it is against where it is.
        if v_cmd:
            speed_err = st.v / v_cmd - 1
            odom_err = odom.x / st.pose.x - 1
        else:
            speed_err = st.w / w_cmd - 1
            left, right = st.wheel_angle           # the true heading change, unwrapped
            turned = r_true * (right - left) / AS_BUILT['track_width_m']
            odom_err = _wrap(odom.yaw - st.pose.yaw) / turned
        errors[name] = (speed_err, odom_err)
    speed_cal, odom_cal = errors['calibrated']
    speed_cfg, odom_cfg = errors['shipped']
    assert abs(speed_cal) < 0.01 and abs(odom_cal) < 0.01, errors
    # The shipped configuration misjudges the robot: 3 % slow straight (smaller wheels), 7.6 %
    # slow turning (smaller wheels on a wider track), and odometry believes the command.
    assert speed_cfg < -0.02 and abs(odom_cfg) > 0.02, errors
