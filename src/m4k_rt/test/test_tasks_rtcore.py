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

pytestmark = pytest.mark.e2e  # starts processes / ROS nodes: the end-to-end tier

SRC = os.path.join(os.path.dirname(__file__), '..')


def _start(procs, tmp_path, control, duration, extra=None):
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump(dict({
        'runtime': {'mlockall': False, 'cpu_dma_latency': False, 'start_delay_ms': 10},
        'control': control}, **(extra or {}))))
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
    # It drove forward; how far and how fast in the 2 s is the CPU's (a make test with this
    # stream under SCHED_IDLE beside three others: 0.37 m, and a last speed of 0).
    assert odoms[-1].x > 0 and max(o.v for o in odoms) > 0, odoms[-1]
    assert any(not o.flags & p.ODOM_MOTOR_STALE for o in odoms)   # the motor answered
    assert motor.angle[0] * 0.1016 == pytest.approx(odoms[-1].x, abs=0.05)
    # the actuator commanded the motor (how many WHEEL_CMDs in the 2 s is the CPU's)
    assert motor.commands
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


def test_guard_without_sensors_blocks_forward_and_turning_but_allows_reverse(procs, tmp_path,
                                                                             peers):
    """No laser: the guard stops forward motion and, since the turn guard cannot see what a
    turn would swing the outline into, turns too (m4k_rt.control.turnguard); reversing (at
    the creep cap) stays allowed, so the robot can back away."""
    proc = _start(procs, tmp_path, {}, 30)          # guard on, stale policy stop, no sensors
    link = peers('cmd', 'motor')
    motor = FakeMotor(link, control_params(None).full_scale_wheel_speed)
    odoms = _drive(link, motor, (0.25, 0.5), 1.5)
    assert odoms[-1].flags & p.ODOM_GUARD
    assert abs(odoms[-1].x) < 0.01
    assert abs(odoms[-1].w) < 0.01
    odoms = _drive(link, motor, (-0.1, 0.0), 1.5)
    # it backs away (how fast at the last sample is the CPU's)
    assert min(o.v for o in odoms) < 0 and odoms[-1].x < odoms[0].x, odoms[-1]
    procs.stop(proc)


def test_bad_control_value_fails_start_up_naming_the_field(procs, tmp_path, m4k_runtime_dir):
    proc = _start(procs, tmp_path, {'linear': {'max_acceleration': -0.37}}, 5)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode != 0
    assert 'control.linear.max_acceleration: must be > 0, got -0.37' in err


def _status_until(link, predicate, timeout, what, each=None):
    """Collect `status` datagrams (calling `each` every 20 ms) until `predicate(got)`."""
    got = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if each is not None:
            each()
        select.select([link.nrt['status'].fileno()], [], [], 0.02)
        got += link.read_all('status')
        if predicate(got):
            return got
    raise AssertionError('timed out after {} s waiting for {}; got kinds {}'.format(
        timeout, what, sorted({h.kind.name for h, _ in got})))


def _rt_status(got):
    return [m for h, m in got if h.kind == p.Kind.RT_STATUS]


def _start_fast(procs, tmp_path, control, monitor_params=None):
    """Start rt_core with a 5 Hz monitor so the status tests take a few seconds."""
    monitor = {'period_ms': 200, 'params': dict(monitor_params or {})}
    return _start(procs, tmp_path, control, 30, {'tasks': {'monitor': monitor}})


def test_rt_status_guard_follows_an_obstacle_reading(procs, tmp_path, peers):
    proc = _start_fast(procs, tmp_path, {'guard': {'use_laser': False}})
    link = peers('status', 'sonar')

    def sonar(range_m):
        def write():
            # stamped now, as the driver stamps its ping: the guard ages a reading from it
            link.write('sonar', p.Kind.SONAR, range_m, p.SONAR_OK, stamp=monotonic_ns())
            link.read_all('sonar')          # the task's triggers, not needed here
        return write

    def guard_is(value):
        def check(got):
            rs = _rt_status(got)
            return bool(rs) and rs[-1].flags & p.RT_FLAG_GUARD_VALID and \
                rs[-1].guard_active == value
        return check

    # free ahead -> not limiting (and the forbidden-call audit is reported as a flag)
    got = _status_until(link, guard_is(0), 10, 'guard off with 3 m free', sonar(3.0))
    assert _rt_status(got)[-1].flags & p.RT_FLAG_AUDIT
    # an obstacle inside stop_distance (0.35 m) -> the collision guard is active
    _status_until(link, guard_is(1), 5, 'guard on with an obstacle at 0.1 m', sonar(0.1))
    # cleared beyond stop_distance + release_margin -> released again
    _status_until(link, guard_is(0), 5, 'guard released at 1 m', sonar(1.0))
    procs.stop(proc)


def test_monitor_forwards_each_device_status_and_marks_a_silent_one_stale(procs, tmp_path,
                                                                         peers):
    # Before rt_core starts: a cycle released before the first report was written may read it
    # late on a loaded machine, and stamps it with its own time.
    t0 = monotonic_ns()
    proc = _start_fast(procs, tmp_path, {}, {'device_stale_s': 1.0})
    link = peers('status', 'motor', 'imu')
    link.write('imu', p.Kind.DEVICE_STATUS, 'imu', 3, p.LEVEL_OK, 0, 0)   # once, then silent

    def motor_reports():                     # every cycle of the test loop (20 ms)
        link.write('motor', p.Kind.DEVICE_STATUS, 'motor', 3, p.LEVEL_WARN, 2, 4)
        link.read_all('motor')
        link.read_all('imu')

    def devices(got):
        return [(h, m) for h, m in got if h.kind == p.Kind.DEVICE_STATUS]

    def seen(device, level):
        return lambda got: any(m.device == device and m.level == level
                               for _, m in devices(got))

    got = _status_until(link, seen('imu', p.LEVEL_OK), 10, 'imu OK forwarded', motor_reports)
    got += _status_until(link, seen('imu', p.LEVEL_STALE), 5, 'imu STALE after 1 s',
                         motor_reports)
    got += _status_until(link, seen('motor', p.LEVEL_WARN), 5, 'motor WARN', motor_reports)
    procs.stop(proc)
    motor = [m for _, m in devices(got) if m.device == 'motor']
    # forwarded as reported (the newest may be STALE: a motor path starved for 1 s)
    assert p.DeviceStatus('motor', 3, p.LEVEL_WARN, 2, 4) in motor
    # stamped with when the RT task received the report, on the same monotonic clock
    assert all(t0 <= h.stamp_ns <= monotonic_ns() for h, _ in devices(got))
    imu = [(h, m) for h, m in devices(got) if m.device == 'imu']
    assert len({h.stamp_ns for h, _ in imu}) == 1        # one report, forwarded each cycle
    # devices that never reported are not forwarded (the bridge judges them by data arrival)
    assert {m.device for _, m in devices(got)} == {'motor', 'imu'}
    # the batch order: device reports come before the RT_STATUS closing the batch
    kinds = [h.kind for h, _ in got]
    last = len(kinds) - 1 - kinds[::-1].index(p.Kind.RT_STATUS)
    assert p.Kind.DEVICE_STATUS in kinds[:last]


def test_monitor_forwards_each_hosts_drop_counters_on_status_and_stat(procs, tmp_path, peers):
    """HOST_DROPS from the driver host's side of two device ports reaches the bridge's port
    and rt_stat's, renamed to the RT-side device and stamped with its arrival; the device
    tasks take it as one of their kinds (not ``unexpected``)."""
    proc = _start_fast(procs, tmp_path, {}, {})
    link = peers('status', 'stat', 'motor', 'led')
    t0 = monotonic_ns()

    def host_reports():                      # every cycle of the test loop (20 ms)
        link.write('motor', p.Kind.HOST_DROPS, 'motor-left', 9_990, 7, 1, 0, 2, 0, 0, 3)
        link.write('led', p.Kind.HOST_DROPS, 'led', 50, 0, 0, 1, 0, 0, 0, 0)
        link.read_all('motor')
        link.read_all('led')

    def drops(got):
        return {m.device: (h, m) for h, m in got if h.kind == p.Kind.HOST_DROPS}

    got = _status_until(link, lambda got: len(drops(got)) == 2, 10, 'both forwarded',
                        host_reports)
    stat = []
    deadline = time.monotonic() + 10
    while len(drops(stat)) < 2:
        assert time.monotonic() < deadline, 'HOST_DROPS not on stat'
        host_reports()
        stat += link.read_all('stat')
        time.sleep(0.02)
    health = []

    def healths():
        return {m.name for h, m in health if h.kind == p.Kind.TASK_HEALTH}
    # one TASK_HEALTH per task, back to back in the task order: a read can end mid-batch
    while not {'actuator', 'led'} <= healths():
        assert time.monotonic() < deadline + 10, 'no actuator and led TASK_HEALTH'
        host_reports()
        health += link.read_all('stat')
        time.sleep(0.02)
    procs.stop(proc)
    for where in (got, stat):
        (hm, motor), (hl, led) = drops(where)['motor'], drops(where)['led']
        assert motor == p.HostDrops('motor', 9_990, 7, 1, 0, 2, 0, 0, 3)
        assert led == p.HostDrops('led', 50, 0, 0, 1, 0, 0, 0, 0)
        assert t0 <= hm.stamp_ns <= monotonic_ns() and t0 <= hl.stamp_ns <= monotonic_ns()
    unexpected = {m.name: m.unexpected for h, m in health if h.kind == p.Kind.TASK_HEALTH}
    assert unexpected['actuator'] == 0 and unexpected['led'] == 0


def test_monitor_rejects_a_bad_device_stale_time(procs, tmp_path, m4k_runtime_dir):
    proc = _start_fast(procs, tmp_path, {}, {'device_stale_s': -1})
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    assert 'tasks.monitor.params.device_stale_s: must be a number > 0' in err


def test_monitor_ships_rt_side_port_counters_with_a_malformed_datagram(procs, tmp_path,
                                                                       peers):
    proc = _start_fast(procs, tmp_path, {})
    link = peers('status', 'cmd')
    link.nrt['cmd'].write(b'MK-not-a-datagram')          # the actuator counts it malformed

    def stats(got):
        return {m.port: m for h, m in got if h.kind == p.Kind.PORT_STATS}

    def cmd_malformed(got):
        # and the actuator has tried the motor port at least once: under load (a confined
        # stream) the first PORT_STATS may come before its first WHEEL_CMD. The monitor sends
        # one PORT_STATS per port back to back, so a read can end mid-round: wait for port 11
        # (the last of the round) too, or the set below sees half a round.
        s = stats(got)
        return (1 in s and s[1].malformed == 1 and s[1].received >= 1
                and 2 in s and s[2].dropped_no_peer > 0 and 11 in s)

    got = _status_until(link, cmd_malformed, 10, 'PORT_STATS of cmd with malformed 1, of '
                        'motor with a WHEEL_CMD dropped, and of the last port')
    procs.stop(proc)
    ports = stats(got)
    # every port of the RT process, with its label, as the RT side sees it
    assert {(n, m.label) for n, m in ports.items()} == {
        (0, 'status'), (1, 'cmd'), (2, 'motor'), (3, 'imu'), (4, 'imu_out'), (5, 'led'),
        (6, 'led_in'), (7, 'sonar'), (8, 'sonar_out'), (9, 'lrf'), (10, 'lrf_out'),
        (11, 'stat')}
    assert ports[0].linked and ports[0].sent > 0          # the monitor's own port
    assert ports[1].linked and ports[1].malformed == 1
    assert not ports[2].linked and ports[2].dropped_no_peer > 0   # WHEEL_CMD, no driver
    assert all(m.malformed == 0 for n, m in ports.items() if n != 1)
