import math
from types import SimpleNamespace

from fake_peers import ctx, FakeMotor, MS, Ports
import pytest

from m4k_rt import protocol as p
from m4k_rt.control.base import MODE_DRIVING, MODE_FAULT, MODE_OBSTACLE
from m4k_rt.control.params import control_params
from m4k_rt.tasks.actuator import ActuatorBody, imu_x_axis, make_actuator, track_slope
from m4k_rt.tasks.state import RobotState

PERIOD = 10 * MS


@pytest.fixture
def rig(m4k_runtime_dir):
    ports = Ports(m4k_runtime_dir, 'cmd', 'motor')
    yield ports
    ports.close()


def build(rig, **control):
    control.setdefault('guard', {'enabled': False})
    params = control_params(control)
    state = RobotState()
    body = ActuatorBody(rig.rt['cmd'], rig.rt['motor'], state, params, 0.01)
    motor = FakeMotor(rig, params.full_scale_wheel_speed)
    return body, motor, state


def run(rig, body, motor, t, cycles, cmd=None, cmd_every=5, before_cycle=None):
    """Simulate `cycles` actuator periods; the bridge sends `cmd` every `cmd_every` cycles."""
    for k in range(cycles):
        t += PERIOD
        if cmd is not None and k % cmd_every == 0:
            rig.write('cmd', p.Kind.VELOCITY_CMD, *cmd, stamp=t)
        if before_cycle:
            before_cycle(t)
        body(ctx(t))
        motor.serve(t + 2 * MS)       # the driver host answers within the period
    return t


def test_drives_the_distance_the_acceleration_limit_implies(rig):
    body, motor, state = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 400, cmd=(0.25, 0.0))
    odoms = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    assert len(odoms) == 401 // 5
    last = odoms[-1]
    t_ramp = 0.25 / 0.37
    ideal = 0.5 * 0.37 * t_ramp ** 2 + 0.25 * (4.0 - t_ramp)
    assert last.x == pytest.approx(ideal, abs=0.02)
    assert abs(last.y) < 1e-6
    assert last.v == pytest.approx(0.25, abs=0.01)
    assert last.flags == 0
    # the simulated wheels really turned that far (odometry is not just integrating commands)
    assert motor.angle[0] * 0.1016 == pytest.approx(last.x, abs=0.01)
    assert state.mode == MODE_DRIVING
    assert state.x == pytest.approx(last.x, abs=0.003)
    # one WHEEL_CMD per cycle, each answered; the reply is consumed by the next cycle
    assert len(motor.commands) == 401
    assert body.counters['encoder_samples'] == 400


def test_first_cycles_are_motor_stale_until_the_first_reply(rig):
    body, motor, state = build(rig)
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.25, 0.0)
    body(ctx(PERIOD))
    assert state.mode == MODE_FAULT
    assert state.odom_flags & p.ODOM_MOTOR_STALE
    motor.serve(PERIOD + MS)
    assert motor.commands[-1] == p.WheelCmd(512, 512, 0)
    body(ctx(2 * PERIOD))
    assert not state.odom_flags & p.ODOM_MOTOR_STALE


def test_latest_command_of_a_cycle_wins_and_garbage_is_counted(rig):
    body, motor, _ = build(rig)
    t = run(rig, body, motor, 0, 1)
    rig.write('cmd', p.Kind.VELOCITY_CMD, 1.0, 0.0)
    rig.nrt['cmd'].write(b'\x00garbage-not-a-datagram')
    rig.write('cmd', p.Kind.VELOCITY_CMD, 0.3, -0.2)
    rig.write('cmd', p.Kind.LED, 1, 2, 3, 4, 1)        # wrong kind for this port
    t = run(rig, body, motor, t, 1)
    assert (body.ctl.cmd_linear, body.ctl.cmd_angular) == (0.3, -0.2)
    assert body.ctl.commands == 1
    assert rig.rt['cmd'].counters.malformed == 1
    assert body.unexpected == 1


def test_nan_command_never_reaches_the_controller(rig):
    body, motor, _ = build(rig)
    t = run(rig, body, motor, 0, 1)
    import struct
    bad = bytearray(p.encode(p.Kind.VELOCITY_CMD, 0, 0, 0.1, 0.0))
    struct.pack_into('<d', bad, p.HEADER_SIZE, math.nan)
    rig.nrt['cmd'].write(bytes(bad))
    run(rig, body, motor, t, 1)
    assert body.ctl.commands == 0
    assert rig.rt['cmd'].counters.malformed == 1


def test_stale_command_brakes_and_is_flagged(rig):
    body, motor, _ = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 150, cmd=(0.25, 0.0))   # last command 5 cycles before the end
    rig.read_all('cmd')
    t = run(rig, body, motor, t, 150)   # 1.5 s of silence: 0.5 s timeout + 0.68 s ramp + margin
    odoms = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    braking = [o for o in odoms if o.flags & p.ODOM_BRAKING]
    assert braking, 'brake flag never set'
    assert not odoms[0].flags & p.ODOM_BRAKING
    assert body.ctl.v == 0.0
    assert odoms[-1].v == pytest.approx(0.0, abs=0.005)
    codes = motor.commands[-1]
    assert (codes.left_code, codes.right_code) == (512, 512)


def test_guard_reading_stops_forward_within_one_cycle(rig):
    body, motor, state = build(rig, guard={'enabled': True, 'use_laser': False})
    sonar = {'range': 2.0}

    def sonar_task(t):           # what the sonar task leaves in the shared state
        state.sonar_range = sonar['range']
        state.sonar_rx_ns = t - MS
    t = run(rig, body, motor, 0, 1, before_cycle=sonar_task)
    t = run(rig, body, motor, t, 150, cmd=(0.25, 0.0), before_cycle=sonar_task)
    assert body.ctl.v == pytest.approx(0.25)
    sonar['range'] = 0.3
    t = run(rig, body, motor, t, 1, before_cycle=sonar_task)
    assert body.ctl.v == 0.0
    assert state.mode == MODE_OBSTACLE
    last = motor.commands[-1]
    assert last.left_code <= 512 and last.right_code <= 512   # not driving on
    # rotation and reverse stay allowed
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.8), before_cycle=sonar_task)
    assert body.ctl.v == 0.0 and body.ctl.w == pytest.approx(0.8)
    t = run(rig, body, motor, t, 100, cmd=(-0.1, 0.0), before_cycle=sonar_task)
    assert body.ctl.v == pytest.approx(-0.1)
    odoms = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    assert any(o.flags & p.ODOM_GUARD for o in odoms)


def test_motor_lost_marks_outputs_stale_and_holds_zero_after_return(rig):
    body, motor, state = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0))
    motor.alive = False
    t = run(rig, body, motor, t, 20, cmd=(0.25, 0.0))
    assert state.mode == MODE_FAULT
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)   # category 1: the zero word brakes
    t = run(rig, body, motor, t, 140, cmd=(0.25, 0.0))     # past the braking time bound
    assert motor.commands[-1] == p.WheelCmd(512, 512, 0)
    odoms = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    assert odoms[-1].flags & p.ODOM_MOTOR_STALE
    motor.alive = True
    t = run(rig, body, motor, t, 30)          # encoders back, no fresh command
    assert not state.odom_flags & p.ODOM_MOTOR_STALE
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)
    assert body.ctl.hold_zero
    run(rig, body, motor, t, 30, cmd=(0.25, 0.0))
    assert body.ctl.v > 0.0
    assert state.mode == MODE_DRIVING


def test_factory_reads_control_section_from_task_params(rig):
    task = SimpleNamespace(name='actuator', period_ns=PERIOD,
                           params={'control': {'odom_every_n': 2}})
    shared = {}
    body = make_actuator(task, rig.rt, shared)
    assert body.params.odom_every_n == 2
    assert shared['robot'] is body.state
    body()                                     # no ctx: the body reads the clock itself
    assert body.cycles == 1


def test_e_stop_contact_under_a_live_command_holds_until_release_and_a_fresh_command(rig):
    # Through the real ports: the motor service reports the contact open (ENCODERS status
    # ESTOP_OPEN) while the bridge keeps commanding; closing the contact restarts nothing;
    # an E_STOP release then holds until a command newer than it.
    body, motor, state = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0))
    assert body.ctl.v == pytest.approx(0.25)
    motor.status = p.ENC_ESTOP_OPEN
    t = run(rig, body, motor, t, 50, cmd=(0.25, 0.0), cmd_every=1)
    assert state.odom_flags & p.ODOM_ESTOP_OPEN and state.odom_flags & p.ODOM_E_STOP
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)      # zero word, enable kept driven
    assert body.ctl.pi_left.integral == 0.0 and body.ctl.pi_right.integral == 0.0
    motor.status = 0                                           # contact closed again
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0), cmd_every=1)
    assert state.odom_flags & p.ODOM_E_STOP and body.ctl.v == 0.0
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)
    rig.write('cmd', p.Kind.E_STOP, 0, stamp=t)               # the explicit release
    t = run(rig, body, motor, t, 50)
    assert state.odom_flags & p.ODOM_HOLD and body.ctl.v == 0.0
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0))        # a fresh command drives
    assert body.ctl.v == pytest.approx(0.25)
    odoms = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    assert any(o.flags & p.ODOM_ESTOP_OPEN for o in odoms)


def test_motor_fault_latches_drops_the_enable_and_only_a_reset_clears_it(rig):
    body, motor, state = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0))
    motor.frozen = list(motor.angle)                           # frozen valid frames
    t = run(rig, body, motor, t, 30, cmd=(0.25, 0.0))
    assert state.odom_flags & p.ODOM_MOTOR_FAULT and state.mode == MODE_FAULT
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)   # category 1: the zero word brakes
    t = run(rig, body, motor, t, 140, cmd=(0.25, 0.0))     # past the braking time bound
    assert motor.commands[-1] == p.WheelCmd(512, 512, 0)   # then the enable drops
    assert state.motor_fault_cause and state.motor_faults == 1
    motor.frozen = None
    t = run(rig, body, motor, t, 50, cmd=(0.25, 0.0))
    assert state.odom_flags & p.ODOM_MOTOR_FAULT                # latched
    rig.read_all('cmd')
    rig.write('cmd', p.Kind.FAULT_RESET, 42, 0, stamp=t)
    t = run(rig, body, motor, t, 20)
    acks = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.FAULT_RESET]
    assert acks == [p.FaultReset(42, 1)]
    assert not state.odom_flags & p.ODOM_MOTOR_FAULT and state.odom_flags & p.ODOM_HOLD
    assert body.ctl.v == 0.0                                    # the old command: held
    t = run(rig, body, motor, t, 100, cmd=(0.25, 0.0))
    assert body.ctl.v == pytest.approx(0.25) and state.motor_fault_cause == 0
    rig.write('cmd', p.Kind.FAULT_RESET, 43, 0, stamp=t)
    run(rig, body, motor, t, 2)
    acks = [m for h, m in rig.read_all('cmd') if h.kind == p.Kind.FAULT_RESET]
    assert acks == [p.FaultReset(43, 0)]                        # nothing was latched


def _factory_shared(runtime_dir, tmp_cfg=None):
    from m4k_rt import config
    cfg = config.load(None, None)
    return SimpleNamespace(config=cfg, runtime_dir=runtime_dir, robot=None)


def test_actuator_starts_latched_when_the_bridge_persisted_an_e_stop(rig, m4k_runtime_dir,
                                                                     capsys):
    from m4k_rt.estop_request import write_request
    shared = _factory_shared(m4k_runtime_dir)
    task = [t for t in shared.config.tasks if t.name == 'actuator'][0]
    body = make_actuator(task, rig.rt, shared)
    assert not body.ctl.estop.engaged
    write_request(m4k_runtime_dir, True)
    shared = _factory_shared(m4k_runtime_dir)
    body = make_actuator(task, rig.rt, shared)
    assert body.ctl.estop.engaged
    err = capsys.readouterr().err
    assert 'e-stop latch ENGAGED at start-up' in err
    assert 'collision guard: top forward speed 2.00 m/s' in err
    write_request(m4k_runtime_dir, False)
    assert not make_actuator(task, rig.rt, _factory_shared(m4k_runtime_dir)).ctl.estop.engaged


def test_guard_weakening_hook_is_refused_without_test_hooks_and_stated_with_them(
        rig, m4k_runtime_dir, monkeypatch, capsys):
    shared = _factory_shared(m4k_runtime_dir)
    task = [t for t in shared.config.tasks if t.name == 'actuator'][0]
    monkeypatch.setenv('M4K_TEST_GUARD_WEAKEN_M', '0.1')
    monkeypatch.delenv('M4K_TEST_HOOKS', raising=False)
    with pytest.raises(ValueError, match='refused'):
        make_actuator(task, rig.rt, shared)
    monkeypatch.setenv('M4K_TEST_HOOKS', '1')
    body = make_actuator(task, rig.rt, _factory_shared(m4k_runtime_dir))
    assert body.guard.weaken == pytest.approx(0.1)
    assert 'WEAKENED by 0.100 m' in capsys.readouterr().err
    monkeypatch.setenv('M4K_TEST_GUARD_WEAKEN_M', '-1')
    with pytest.raises(ValueError, match='metres'):
        make_actuator(task, rig.rt, _factory_shared(m4k_runtime_dir))


def test_top_speed_is_capped_where_the_sensors_cannot_see_far_enough(rig):
    # a sluggish amplifier (1.4 s: t_react about 2 s) and weak brakes: d(v) outgrows 5.375 m
    # below 2 m/s
    from m4k_rt.tasks.actuator import guard_plan
    params = control_params({'guard': {'amplifier_lag': 1.4, 'brake_deceleration': 0.5}})
    plan = guard_plan(params, 0.01, None, {'body': {'length': 0.45},
                                           'sensors': {'laser': {'pose': [0, 0, 0.2]}}})
    assert plan.top_speed == pytest.approx(plan.sensor_speed) and plan.top_speed < 2.0
    assert 'CAPPED BY THE SENSORS' in plan.line()
    state = RobotState()
    body = ActuatorBody(rig.rt['cmd'], rig.rt['motor'], state, params, 0.01, plan=plan)
    motor = FakeMotor(rig, params.full_scale_wheel_speed)

    def clear(t):
        state.sonar_range = state.laser_front_min = math.inf
        state.sonar_rx_ns = state.laser_rx_ns = t - MS
    t = run(rig, body, motor, 0, 1, before_cycle=clear)
    run(rig, body, motor, t, 800, cmd=(2.0, 0.0), before_cycle=clear)
    assert body.ctl.v == pytest.approx(plan.top_speed)
    assert state.odom_flags & p.ODOM_CLAMPED


def test_the_guards_corridor_takes_in_the_wheels_outside_the_body(rig, m4k_runtime_dir):
    # The shipped robot: a 0.28 m body on wheels whose outer faces are 0.225 m from the centre
    # line. The actuator's memory and the laser's corridor are that wide plus the lateral
    # margin, so a 3 cm leg 0.21 m off the line (past the body, in the wheel's path) is in it.
    import math

    from m4k_rt.control.footprint import half_width_of
    from m4k_rt.control.guard import FrontCorridor
    shared = _factory_shared(m4k_runtime_dir)
    raw = shared.config.raw
    task = [t for t in shared.config.tasks if t.name == 'actuator'][0]
    body = make_actuator(task, rig.rt, shared)
    wheel_face = raw['control']['track_width'] / 2 + raw['robot']['wheel_width'] / 2
    margin = raw['control']['guard']['lateral_margin']
    assert wheel_face > raw['robot']['body']['width'] / 2
    assert body.feed.half_width == pytest.approx(wheel_face + margin)
    corridor = FrontCorridor(half_width_of(raw['robot'], raw['control']['track_width'])
                             + margin, 0.225)
    inc = math.radians(0.352)
    a = math.atan2(0.21, 3.0)
    ranges = [0] * 682
    i = round((a + math.radians(120.0)) / inc)
    ranges[i] = round(math.hypot(3.0, 0.21) * 1000)
    assert corridor.minimum(-math.radians(120.0), inc, 0.02, 5.6, ranges) == pytest.approx(
        3.0 - 0.225, abs=0.01)


def test_a_cycle_that_raises_brakes_then_cuts_the_enable_and_stays_failed(rig):
    # a defect inside the body (here: the guard's memory raising) must not leave the last
    # WHEEL_CMD driving until the heartbeat times out, nor resume on a suspect state
    body, motor, state = build(rig)
    t = run(rig, body, motor, 0, 1)
    t = run(rig, body, motor, t, 150, cmd=(0.5, 0.0))
    assert motor.commands[-1].enable == 1 and motor.commands[-1].left_code > 512
    class Broken:
        def __getattr__(self, name):
            raise ZeroDivisionError(name)

    real, body.feed = body.feed, Broken()
    with pytest.raises(ZeroDivisionError):
        body(ctx(t + PERIOD))
    t += PERIOD
    motor.serve(t + 2 * MS)
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)   # category 1: the zero word brakes
    assert state.mode == MODE_FAULT
    body.feed = real                                        # the defect is gone: still failed
    bound = body.ctl.fault_brake_ns // PERIOD
    t = run(rig, body, motor, t, bound - 2, cmd=(0.5, 0.0))
    assert motor.commands[-1] == p.WheelCmd(512, 512, 1)
    t = run(rig, body, motor, t, 3, cmd=(0.5, 0.0))
    assert motor.commands[-1] == p.WheelCmd(512, 512, 0)   # then the enable drops
    run(rig, body, motor, t, 50, cmd=(0.5, 0.0))
    assert all(c == p.WheelCmd(512, 512, 0) for c in motor.commands[-50:])
    assert state.mode == MODE_FAULT and body.counters['failed_cycles'] == 1 + (bound - 2) + 3 + 50


def _q_rpy(roll, pitch, yaw):
    """(x, y, z, w) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def _q_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


@pytest.mark.parametrize('mount', [(0.0, 0.0, 0.0), (0.0, 0.0, math.pi / 2), (math.pi, 0.0, 0.0),
                                   (0.1, -0.2, 2.5)],
                         ids=['upright', 'turned-90', 'upside-down', 'skewed'])
@pytest.mark.parametrize('pitch_deg, heading', [(0.0, 0.3), (4.8, 1.0), (-3.0, -2.0)])
def test_track_slope_is_the_bases_pitch_whatever_the_imus_mount(mount, pitch_deg, heading):
    # the base pitched on a ramp at some heading; the IMU mounted at ``mount`` reports
    # imu_link's orientation (the base's times the mount): the slope along base_link x is
    # -sin(pitch) of the base, not of the IMU
    robot = {'sensors': {'imu': {'pose': [0.1, 0.0, 0.2, *mount]}}}
    base = _q_rpy(0.05, math.radians(pitch_deg), heading)
    imu = _q_mul(base, _q_rpy(*mount))
    slope = track_slope(*imu, imu_x_axis(robot))
    assert slope == pytest.approx(-math.sin(math.radians(pitch_deg)), abs=1e-9)
    assert math.isnan(track_slope(math.nan, math.nan, math.nan, math.nan, imu_x_axis(robot)))
    assert imu_x_axis({}) == (1.0, 0.0, 0.0)
