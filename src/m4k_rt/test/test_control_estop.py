"""The e-stop latch: pure rules, the controller's ramp, parameters, and the actuator's wiring."""

import math

from fake_peers import ctx, FakeMotor, MS, Ports
import pytest
from test_control_base import drive, make, Plant

from m4k_rt import protocol as p
from m4k_rt.control.base import MODE_E_STOP, MODE_FAULT
from m4k_rt.control.estop import EStopLatch, ramp_to_zero
from m4k_rt.control.params import control_params, ControlConfigError
from m4k_rt.protocol import ODOM_E_STOP, ODOM_HOLD
from m4k_rt.tasks.actuator import ActuatorBody
from m4k_rt.tasks.state import RobotState

PERIOD = 10 * MS


# --- the latch ---------------------------------------------------------------------------------

def test_ramp_to_zero_never_crosses_zero():
    assert ramp_to_zero(0.25, 0.37, 0.01) == pytest.approx(0.2463)
    assert ramp_to_zero(-0.25, 0.37, 0.01) == pytest.approx(-0.2463)
    assert ramp_to_zero(0.002, 0.37, 0.01) == 0.0
    assert ramp_to_zero(-0.002, 0.37, 0.01) == 0.0


def test_latch_blocks_until_a_command_after_the_release():
    e = EStopLatch(0.37, 1.85)
    assert not e.blocking and e.command()
    e.engage()
    assert e.blocking and not e.command()          # a command during the latch drives nothing
    e.release()
    assert e.blocking and not e.engaged and e.holding
    assert e.command()                              # the first command after the release
    assert not e.blocking
    assert (e.engagements, e.releases) == (1, 1)


def test_repeated_release_does_not_rearm_the_hold():
    e = EStopLatch(0.37, 1.85)
    e.engage()
    e.release()
    e.command()
    e.release()                                     # e.g. a latched publisher re-delivering
    assert not e.blocking and e.releases == 1


def test_latch_refuses_a_deceleration_that_is_not_positive():
    for bad in (0.0, -1.0, math.nan, math.inf, True):
        with pytest.raises(ValueError, match='linear_deceleration'):
            EStopLatch(bad, 1.0)


# --- parameters --------------------------------------------------------------------------------

def test_e_stop_deceleration_defaults_to_the_axis_maximum():
    params = control_params({'linear': {'max_deceleration': 0.5}})
    assert params.e_stop_linear_deceleration == 0.5
    assert params.e_stop_angular_deceleration == params.angular.max_acceleration
    params = control_params({'e_stop': {'linear_deceleration': 1.2}})
    assert params.e_stop_linear_deceleration == 1.2


@pytest.mark.parametrize('section, field', [
    ({'e_stop': {'linear_deceleration': 0.1}}, 'control.e_stop.linear_deceleration'),
    ({'e_stop': {'angular_deceleration': -2.0}}, 'control.e_stop.angular_deceleration'),
    ({'e_stop': {'linear_deceleration': 'fast'}}, 'control.e_stop.linear_deceleration'),
    ({'e_stop': {'brake': 1.0}}, 'control.e_stop.brake'),
])
def test_configure_fails_with_a_bad_e_stop_deceleration(section, field):
    with pytest.raises(ControlConfigError) as exc:
        control_params(section)
    assert exc.value.field == field


# --- the controller ----------------------------------------------------------------------------

def test_e_stop_ramps_down_at_its_deceleration_from_the_first_cycle():
    ctl, params = make(e_stop={'linear_deceleration': 1.0})
    plant = Plant(params.full_scale_wheel_speed)
    t = drive(ctl, plant, 1, 0)
    t = drive(ctl, plant, 100, t, cmd=(0.25, 0.3), cmd_every=1)
    assert ctl.v == pytest.approx(0.25)
    ctl.e_stop(True)
    t = drive(ctl, plant, 1, t)
    assert ctl.v == pytest.approx(0.25 - 1.0 * 0.01)             # this cycle, at 1 m/s^2
    assert ctl.w == pytest.approx(0.3 - params.angular.max_acceleration * 0.01)
    assert ctl.flags & ODOM_E_STOP and ctl.mode == MODE_E_STOP
    # commands during the latch are ignored: 0.25 m/s at 1 m/s^2 is 25 cycles
    t = drive(ctl, plant, 24, t, cmd=(0.25, 0.3), cmd_every=1)
    assert ctl.v == 0.0 and ctl.w == 0.0
    assert ctl.commands_blocked == 24
    t = drive(ctl, plant, 50, t, cmd=(0.25, 0.0), cmd_every=1)
    assert (ctl.left_code, ctl.right_code) == (512, 512)


def test_release_holds_until_a_newer_command():
    ctl, params = make()
    plant = Plant(params.full_scale_wheel_speed)
    t = drive(ctl, plant, 1, 0)
    t = drive(ctl, plant, 50, t, cmd=(0.25, 0.0), cmd_every=1)
    ctl.e_stop(True)
    t = drive(ctl, plant, 100, t)
    ctl.e_stop(False)
    t = drive(ctl, plant, 20, t)          # the last command (0.25 m/s) is from before: held
    assert ctl.v == 0.0 and ctl.flags & ODOM_HOLD and not ctl.flags & ODOM_E_STOP
    assert ctl.mode != MODE_E_STOP
    drive(ctl, plant, 5, t, cmd=(0.25, 0.0), cmd_every=1)
    assert ctl.v > 0.0 and not ctl.flags & (ODOM_HOLD | ODOM_E_STOP)


def test_latch_survives_motor_stale_and_is_still_flagged():
    ctl, params = make()
    plant = Plant(params.full_scale_wheel_speed)
    t = drive(ctl, plant, 1, 0)
    ctl.e_stop(True)
    t += 500 * MS                         # no encoders: motor stale
    ctl.step(t)
    assert ctl.mode == MODE_FAULT and ctl.flags & ODOM_E_STOP
    t = drive(ctl, plant, 30, t, cmd=(0.25, 0.0), cmd_every=1)
    assert ctl.v == 0.0 and ctl.mode == MODE_E_STOP


def test_reset_pose_zeroes_the_pose_and_keeps_integrating():
    ctl, params = make()
    plant = Plant(params.full_scale_wheel_speed)
    t = drive(ctl, plant, 1, 0)
    t = drive(ctl, plant, 100, t, cmd=(0.25, 0.2), cmd_every=1)
    assert ctl.odom.x > 0.1
    v = ctl.odom.v
    ctl.reset_pose()
    assert (ctl.odom.x, ctl.odom.y, ctl.odom.yaw) == (0.0, 0.0, 0.0)
    assert ctl.odom.v == v
    drive(ctl, plant, 10, t, cmd=(0.25, 0.2), cmd_every=1)
    assert ctl.odom.x == pytest.approx(0.025, abs=0.005)     # 0.1 s at 0.25 m/s, not a jump


# --- the actuator's port order -----------------------------------------------------------------

@pytest.fixture
def rig(m4k_runtime_dir):
    ports = Ports(m4k_runtime_dir, 'cmd', 'motor')
    yield ports
    ports.close()


def _build(rig):
    params = control_params({'guard': {'enabled': False}})
    body = ActuatorBody(rig.rt['cmd'], rig.rt['motor'], RobotState(), params, 0.01)
    return body, FakeMotor(rig, params.full_scale_wheel_speed)


def _cycle(rig, body, motor, t):
    body(ctx(t))
    motor.serve(t + 2 * MS)
    return t + PERIOD


def test_command_before_a_release_in_the_same_cycle_does_not_restart(rig):
    body, motor = _build(rig)
    t = _cycle(rig, body, motor, PERIOD)
    rig.write('cmd', p.Kind.E_STOP, 1)
    t = _cycle(rig, body, motor, t)
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0)
    rig.write('cmd', p.Kind.E_STOP, 0)
    for _ in range(20):
        t = _cycle(rig, body, motor, t)
    assert body.ctl.v == 0.0 and body.state.odom_flags & p.ODOM_HOLD
    rig.write('cmd', p.Kind.E_STOP, 0)
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0)     # after the release: drives
    t = _cycle(rig, body, motor, t)
    assert body.ctl.v > 0.0
    assert body.counters['e_stop_engagements'] == 1


def test_odom_reset_is_acknowledged_with_its_id_and_the_pose_is_zero(rig):
    body, motor = _build(rig)
    t = _cycle(rig, body, motor, PERIOD)
    for _ in range(50):
        rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0)
        t = _cycle(rig, body, motor, t)
    rig.read_all('cmd')
    rig.write('cmd', p.Kind.ODOM_RESET, 77)
    t = _cycle(rig, body, motor, t)
    for _ in range(5):
        t = _cycle(rig, body, motor, t)
    got = rig.read_all('cmd')
    kinds = [h.kind for h, _ in got]
    assert kinds[0] == p.Kind.ODOM_RESET and got[0][1] == p.OdomReset(77)
    odom = [m for h, m in got if h.kind == p.Kind.ODOMETRY][0]
    assert odom.x < 0.02                   # at most five cycles of motion since the reset


def test_set_pose_is_acknowledged_with_the_pose_as_set(rig):
    body, motor = _build(rig)
    t = _cycle(rig, body, motor, PERIOD)
    rig.read_all('cmd')
    rig.write('cmd', p.Kind.SET_POSE, 9, 1.5, -2.0, 7.0)      # yaw wraps into (-pi, pi]
    t = _cycle(rig, body, motor, t)
    got = rig.read_all('cmd')
    assert got[0][0].kind == p.Kind.SET_POSE
    ack = got[0][1]
    assert (ack.request_id, ack.x, ack.y) == (9, 1.5, -2.0)
    assert ack.yaw == pytest.approx(7.0 - 2 * math.pi)
    for _ in range(6):                       # ODOMETRY goes out every odom_every_n cycles
        t = _cycle(rig, body, motor, t)
    odom = [m for h, m in got + rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY][-1]
    assert (odom.x, odom.y) == pytest.approx((1.5, -2.0), abs=1e-6)


def test_applied_velocity_is_what_the_actuator_drives_after_limits_and_e_stop(rig):
    body, motor = _build(rig)
    t = _cycle(rig, body, motor, PERIOD)
    for _ in range(10):                      # 5 m/s asked: the limiter ramps at 0.37 m/s^2
        rig.write('cmd', p.Kind.VELOCITY_CMD, 5.0, 0.0)
        t = _cycle(rig, body, motor, t)
    applied = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.APPLIED_VELOCITY]
    assert applied and all(0.0 < a.linear_x <= 0.37 * 0.01 * 10 + 1e-9 for a in applied[1:])
    # sent with each ODOMETRY: the ramp's value of that cycle, rising, never the 5 m/s asked
    assert [a.linear_x for a in applied] == sorted(a.linear_x for a in applied)
    assert 0.0 < applied[-1].linear_x <= body.ctl.v
    rig.write('cmd', p.Kind.E_STOP, 1)
    for _ in range(20):
        rig.write('cmd', p.Kind.VELOCITY_CMD, 5.0, 0.0)
        t = _cycle(rig, body, motor, t)
    applied = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.APPLIED_VELOCITY]
    assert applied[-1] == p.AppliedVelocity(0.0, 0.0)   # the latch, whatever is commanded
