"""rt_core with the default config runs the robot bodies; fake NRT peers in this process."""

import os
import select
import signal
import time

from fake_peers import FakeMotor, NrtPeers
import pytest
import yaml

from m4k_rt import protocol as p
from m4k_rt.control.params import control_params
from m4k_rt.timerfd import monotonic_ns

SRC = os.path.join(os.path.dirname(__file__), '..')


def _start(procs, tmp_path, control, duration):
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump({
        'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10},
        'control': control}))
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [os.path.abspath(SRC)] + [x for x in env.get('PYTHONPATH', '').split(os.pathsep) if x])
    return procs.start(['python', '-m', 'm4k_rt.rt_core', '--config', str(overlay),
                        '--duration', str(duration)], env=env)


def _drive(peers, motor, cmd, seconds):
    """Bridge + motor handler for `seconds` of real time; return the ODOMETRY received."""
    odoms = []
    next_cmd = 0.0
    end = time.monotonic() + seconds
    fds = [peers.nrt['motor'].fileno(), peers.nrt['cmd'].fileno()]
    while time.monotonic() < end:
        if time.monotonic() >= next_cmd:
            peers.write('cmd', p.Kind.VELOCITY_CMD, *cmd)
            next_cmd = time.monotonic() + 0.05
        select.select(fds, [], [], 0.01)
        motor.serve(monotonic_ns())
        odoms += [m for h, m in peers.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    return odoms


@pytest.fixture
def peers(m4k_runtime_dir):
    made = []

    def open_(*labels):
        made.append(NrtPeers(m4k_runtime_dir, *labels))
        return made[-1]
    yield open_
    for x in made:
        x.close()


def test_default_config_drives_the_motor_and_odometry_moves(procs, tmp_path, peers):
    proc = _start(procs, tmp_path, {'guard': {'enabled': False}}, 30)
    link = peers('cmd', 'motor')
    motor = FakeMotor(link, control_params(None).full_scale_wheel_speed)
    odoms = _drive(link, motor, (0.25, 0.0), 2.0)
    assert len(odoms) > 10
    assert odoms[-1].x > 0.1
    assert odoms[-1].v > 0.1
    assert not odoms[-1].flags & p.ODOM_MOTOR_STALE
    assert motor.angle[0] * 0.1016 == pytest.approx(odoms[-1].x, abs=0.05)
    # every WHEEL_CMD was answered: no gaps of several cycles on the motor port
    assert len(motor.commands) > 100
    # stop commanding: the stale-command brake brings the wheels to zero
    odoms = _drive_silent(link, motor, 2.0)
    assert any(o.flags & p.ODOM_BRAKING for o in odoms)
    assert motor.commands[-1].left_code == 512
    os.killpg(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    # every robot body ran (with or without its peers) and none raised
    for name in ('actuator', 'imu', 'led', 'sonar', 'lrf'):
        line = next(x for x in err.splitlines() if x.startswith(f'rt_core: task {name}: '))
        assert ' body errors 0 ' in line, line
        assert int(line.split(' cycles ')[1].split()[0]) > 0, line


def _drive_silent(peers, motor, seconds):
    odoms = []
    end = time.monotonic() + seconds
    fd = peers.nrt['motor'].fileno()
    while time.monotonic() < end:
        select.select([fd], [], [], 0.01)
        motor.serve(monotonic_ns())
        odoms += [m for h, m in peers.read_all('cmd') if h.kind == p.Kind.ODOMETRY]
    return odoms


def test_guard_without_sensors_blocks_forward_but_allows_turning(procs, tmp_path, peers):
    proc = _start(procs, tmp_path, {}, 30)          # guard on, stale policy stop, no sensors
    link = peers('cmd', 'motor')
    motor = FakeMotor(link, control_params(None).full_scale_wheel_speed)
    odoms = _drive(link, motor, (0.25, 0.5), 1.5)
    assert odoms[-1].flags & p.ODOM_GUARD
    assert abs(odoms[-1].x) < 0.01
    assert odoms[-1].w > 0.2
    procs.stop(proc)


def test_bad_control_value_fails_start_up_naming_the_field(procs, tmp_path, m4k_runtime_dir):
    proc = _start(procs, tmp_path, {'linear': {'max_acceleration': -0.37}}, 5)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode != 0
    assert 'control.linear.max_acceleration: must be > 0, got -0.37' in err
