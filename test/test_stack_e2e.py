"""The whole stack end to end: bringup (rt_core + driver_host sim + bridge) seen through ROS.

The test process is a plain ROS 2 user: it publishes cmd_vel / led and subscribes to what the
bridge publishes. The simulated room is config/devices.yaml's (paper Fig. 8); the overlay moves
the start to y = 0.9 m so the straight path ahead is free up to the wall at x = 4.2 m and the
collision guard (obstacle at x = 1.5 m, |y| <= 0.25 m) stays out of the way.
"""

import math
import os
import signal
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Imu, LaserScan, Range
from test_bringup import BASE_OVERLAY, cmdline, start_bringup, write_overlay
import yaml

from m4k_drivers.simbus import read_truth
from m4k_msgs.msg import RtStatus
from m4k_rt.control.limiter import SpeedLimiter
from m4k_rt.control.params import control_params
from m4k_testing import child_pids

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
START = [0.0, 0.9, 0.0]
WALL_X = 4.2                 # devices.yaml world.walls.rectangle xmax
SONAR_X = 0.225              # devices.yaml devices.sonar.mount x (laser mount: 0, 0)
# Odometry speed at rest is encoder quantization noise: one 12-bit count on one wheel over the
# 50 ms twist window (control.odom_velocity_window) is 2 pi / 4096 / 0.05 * 0.1016 / 2 =
# 0.0016 m/s of body speed (0.008 m/s over a single 10 ms difference).
STILL = 0.02
pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process


def _control():
    with open(os.path.join(ROOT, 'config', 'control.yaml'), encoding='utf-8') as f:
        return yaml.safe_load(f)['control']


class RosUser:
    """A test node in its own Context: publishers, collected messages, spinning helpers."""

    def __init__(self):
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('stack_e2e_user', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.got = {}
        for name, typ, qos in (('odom', Odometry, 10), ('imu', Imu, qos_profile_sensor_data),
                               ('scan', LaserScan, qos_profile_sensor_data),
                               ('sonar', Range, qos_profile_sensor_data),
                               ('diagnostics', DiagnosticArray, 10),
                               ('rt_status', RtStatus, 10)):
            box = self.got[name] = []
            self.node.create_subscription(typ, name, box.append, qos)

    def spin_for(self, seconds, each=None, period=None):
        """Spin ``seconds``; call ``each`` every ``period`` seconds (e.g. publish at 20 Hz)."""
        end = time.monotonic() + seconds
        next_call = time.monotonic()
        while time.monotonic() < end:
            if each is not None and time.monotonic() >= next_call:
                each()
                next_call += period
            self.executor.spin_once(timeout_sec=0.005 if each is not None else 0.05)

    def spin_until(self, predicate, timeout, what, each=None, period=0.05):
        end = time.monotonic() + timeout
        next_call = time.monotonic()
        while time.monotonic() < end:
            if each is not None and time.monotonic() >= next_call:
                each()
                next_call += period
            self.executor.spin_once(timeout_sec=0.01)
            if predicate():
                return
        raise AssertionError('timed out after {} s waiting for {}'.format(timeout, what))

    def wait_still(self, timeout, window=0.3, tol=0.002):
        """Wait until odom's position stays within ``tol`` for ``window`` s of odom time.

        Position, not the odom speed: the speed is differenced from 12-bit encoders and
        carries quantization noise (and rare spikes) even at rest. The window is measured on
        the odometry's own stamps, not on this process's clock: when the odometry stream
        stalls (a starved bridge or test process), no new samples is no evidence of rest.
        """
        odom = self.got['odom']

        def still():
            return (_stamp_ns(odom[-1]) - _still_since_stamp(odom, tol)) * 1e-9 >= window

        self.spin_until(still, timeout, 'the robot to stand still')

    def publisher(self, typ, topic):
        """Create a publisher and wait until the bridge's subscription matched it."""
        pub = self.node.create_publisher(typ, topic, 10)
        self.spin_until(lambda: pub.get_subscription_count() > 0, 20, topic + ' matched')
        return pub

    def close(self):
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def stack(procs, tmp_path, m4k_runtime_dir, request):
    extra = {'world': {'start': START}}
    extra.update(getattr(request, 'param', {}))
    overlay = write_overlay(tmp_path, extra)
    proc = start_bringup(procs, tmp_path, m4k_runtime_dir, overlay, extra=['--no-status'])
    user = RosUser()
    try:
        # Ready = odometry flows (RT process, driver host and bridge all linked).
        user.spin_until(lambda: user.got['odom'] or proc.poll() is not None, 40, 'odom')
        assert proc.poll() is None, (tmp_path / 'bringup.err').read_text()[-3000:]
        yield user, proc, tmp_path
    finally:
        user.close()
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(40)


RT_PORTS = {'status': 0, 'cmd': 1, 'motor': 2, 'imu': 3, 'imu_out': 4, 'led': 5, 'led_in': 6,
            'sonar': 7, 'sonar_out': 8, 'lrf': 9, 'lrf_out': 10, 'stat': 11}


def _full_diagnostics(d):
    """Tell whether a DiagnosticArray has all 6 tasks and every device from DEVICE_STATUS."""
    tasks = sum(s.name.startswith('m4k_rt: task') for s in d.status)
    devices = sum(s.name.startswith('m4k_drivers: ') and any(
        kv.key == 'source' and kv.value == 'device_status' for kv in s.values)
        for s in d.status)
    return tasks == 6 and devices == 5


def _devices_ok(d):
    """Tell whether every device of a DiagnosticArray reads OK (a full one: a fresher one
    may rightly show the motor in ERROR for a moment, encoders stale on a starved stack)."""
    return _full_diagnostics(d) and all(s.level == b'\x00' for s in d.status
                                        if s.name.startswith('m4k_drivers: '))


def _x(user):
    return user.got['odom'][-1].pose.pose.position.x


def _stamp_ns(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _rt_profile_distance(arrivals_ns, v, params, period_s=0.01):
    """Return the distance the RT actuator should drive for commands arriving at these times.

    The actuator's command handling, replayed: the target is ``v`` while the newest command
    is at most ``cmd_vel_timeout`` old, else 0 (braking), through the same speed limiter
    (acceleration and deceleration limits) every period, integrated until it is back at rest.
    A gap in the delivered commands longer than the timeout (a starved publisher or bridge)
    therefore brakes the model exactly as it brakes the robot.
    """
    lin = params.linear
    limiter = SpeedLimiter(max_velocity=lin.max_velocity, max_acceleration=lin.max_acceleration,
                           max_deceleration=lin.max_deceleration)
    timeout_ns = params.cmd_vel_timeout * 1e9
    step_ns = round(period_s * 1e9)
    t, i, dist = arrivals_ns[0], 0, 0.0
    while True:
        while i + 1 < len(arrivals_ns) and arrivals_ns[i + 1] <= t:
            i += 1
        target = v if t - arrivals_ns[i] <= timeout_ns else 0.0
        speed = limiter.step(target, period_s)
        dist += speed * period_s
        t += step_ns
        if target == 0.0 and speed == 0.0 and i == len(arrivals_ns) - 1:
            return dist


def _bridge_cmd_value(user, key):
    """Return a value of the bridge's latest cmd_vel diagnostics (0 before there is one)."""
    for d in reversed(user.got['diagnostics']):
        for st in d.status:
            if st.name == 'm4k_bridge: cmd_vel':
                return float({kv.key: kv.value for kv in st.values}[key])
    return 0


def _still_since_stamp(odom, tol=0.002):
    """Return the odom stamp (RT time on the ROS clock) since which the robot has stood still."""
    end = odom[-1].pose.pose.position
    first = odom[-1]
    for msg in reversed(odom):
        p = msg.pose.pose.position
        if math.hypot(p.x - end.x, p.y - end.y) > tol:
            break
        first = msg
    return _stamp_ns(first)


# The RT process's ports over either transport (runtime.transport): the same behaviour.
SHM = {'runtime': {**BASE_OVERLAY['runtime'], 'transport': 'shm'}}
TRANSPORTS = pytest.mark.parametrize('stack', [{}, SHM], ids=['socket', 'shm'], indirect=True)


def _rt_ring_maps(proc):
    """Return how many XDDP shm regions rt_core (a child of ``proc``) has mapped."""
    pids = [p for p in child_pids(proc.pid) if 'm4k_rt.rt_core' in cmdline(p)]
    assert pids, 'no rt_core process'
    with open('/proc/{}/maps'.format(pids[0]), encoding='utf-8') as f:
        return sum('/memfd:m4k-xddp' in line for line in f)


def test_drive_distance_follows_the_limits_and_the_robot_stops_after_the_timeout(
        stack, m4k_runtime_dir):
    user, _, _ = stack
    theta0 = read_truth(m4k_runtime_dir)['theta']      # the simulator's, not odometry's
    params = control_params(_control())
    v = 0.25
    dec = params.linear.max_deceleration or params.linear.max_acceleration
    timeout = params.cmd_vel_timeout
    x0 = _x(user)
    y0 = user.got['odom'][-1].pose.pose.position.y
    pub = user.publisher(Twist, 'cmd_vel')
    # The expected drive comes from the commands as DDS delivered them (a subscriber next to
    # the bridge's), not from this process's publishing loop: on a loaded machine either may be
    # starved, and the RT actuator acts on what arrives, when it arrives.
    # Stamped by DDS on reception (MessageInfo received_timestamp, system clock like the odom
    # stamps), not when this process's executor gets to the callback: a starved test process
    # ran its first callbacks 0.5 s late, which made the expected drive 13 % short.
    delivered = []
    cmd = Twist()

    def on_cmd(msg, info):
        if msg.linear.x == v:
            delivered.append(info['received_timestamp'])

    user.node.create_subscription(Twist, 'cmd_vel', on_cmd, 100)
    user.spin_until(lambda: pub.get_subscription_count() >= 2, 20, 'cmd_vel matched twice')
    # Warm the path up with zero commands until the bridge reports forwarding them: a matched
    # publisher does not mean the bridge's reader has matched it yet, and the first samples
    # of a fresh DDS link can reach the bridge hundreds of ms late (seen: the drive started
    # 0.15 s late, 4 % short) -- a latency of discovery, not of the control under test.
    user.spin_until(lambda: _bridge_cmd_value(user, 'forwarded') > 0, 20,
                    'the bridge forwarding cmd_vel', each=lambda: pub.publish(cmd), period=0.05)
    cmd.linear.x = v
    user.spin_for(4.0, each=lambda: pub.publish(cmd), period=0.05)
    # Stop publishing while moving: the RT actuator keeps the command for cmd_vel_timeout,
    # then brakes at the deceleration limit.
    user.wait_still(10)
    assert len(delivered) > 40, len(delivered)
    # It kept driving on the commands and stopped after the last one delivered (on the RT's
    # clock, odom stamps), then stood still, not creeping.
    stopped_after = (_still_since_stamp(user.got['odom']) - delivered[-1]) * 1e-9
    assert stopped_after > 0, stopped_after
    x_stop = _x(user)
    user.spin_for(0.5)
    speeds = [o.twist.twist.linear.x for o in user.got['odom'][-10:]]
    assert abs(sum(speeds) / len(speeds)) < STILL, speeds
    assert abs(_x(user) - x_stop) < 0.005   # stopped, not creeping
    # Never further than the limits let the delivered commands take it: at most v while a
    # command is live (the delivery span, plus a timeout of slack for the RT side's receipt
    # of the last one, plus the timeout itself), then the braking ramp. A load only shortens
    # a drive; how close it comes to the limiter's exact profile and how long the stop took
    # are figures of the machine's load, printed below and measured with their spread by
    # `make scenarios` (open_hall, corridor: distance within the limiter's ramp).
    expected = _rt_profile_distance(delivered, v, params)
    end = user.got['odom'][-1].pose.pose.position
    travelled = math.hypot(end.x - x0, end.y - y0)
    span = (delivered[-1] - delivered[0]) * 1e-9
    assert 0 < travelled <= v * (span + 2 * timeout) + v * v / (2 * dec), (travelled, span)
    # Straight: the wheels are driven alike. Before the speed feedback had a minimum baseline,
    # one burst of queued encoder replies could turn the robot by up to 7 degrees.
    assert abs(end.y - y0) < 0.2 * travelled
    # Straight on ground truth (the simulator's heading), to the original 3 degrees: kept as
    # the one figure of this test, because it is a code's, not the load's: the motor handler's
    # one-stamp-for-two-wheels error (fixed in 1bca5bd) turned straight drives 1.3 deg/m, 0.18
    # since, and a change meant to be equivalent turned one 3.2 degrees in every run
    # (docs/design-notes.md, 9b). This module runs in make test's serial stream (calm CPU).
    turned = math.degrees(math.remainder(read_truth(m4k_runtime_dir)['theta'] - theta0,
                                         2.0 * math.pi))
    assert abs(turned) < 3.0, turned
    print(f"straight drive: travelled {travelled:.3f} m of the profile's {expected:.3f} m, "
          f'stopped {stopped_after:.2f} s after the last command (timeout {timeout} s), '
          f'turned {turned:.2f} deg on ground truth, drift {end.y - y0:+.3f} m')
    odom = user.got['odom'][-1]
    assert (odom.header.frame_id, odom.child_frame_id) == ('odom', 'base_footprint')


def test_sensors_diagnostics_and_rt_status_show_the_simulated_room(stack):
    user, _, _ = stack

    def complete(m):
        # Six tasks cycling, every port listed, and over a second of motor exchange behind it
        # (the counters below are checked on such a status, whenever it arrives).
        by = {p.label: p for p in m.ports}
        return (len(m.tasks) == 6 and all(t.cycles for t in m.tasks) and
                by.keys() == RT_PORTS.keys() and by['motor'].sent > 100 and
                by['motor'].received > 100 and by['imu_out'].sent > 100)

    def ready():
        g = user.got
        return (g['imu'] and g['scan'] and g['sonar'] and
                any(complete(m) for m in g['rt_status']) and
                any(_devices_ok(d) for d in g['diagnostics']))

    user.spin_until(ready, 20, 'imu, scan, sonar, rt_status, diagnostics with every device OK')
    imu = user.got['imu'][-1]
    assert imu.header.frame_id == 'imu_link'
    assert imu.linear_acceleration.z == pytest.approx(9.81, abs=0.5)   # level, at rest
    q = imu.orientation
    assert math.isclose(q.x ** 2 + q.y ** 2 + q.z ** 2 + q.w ** 2, 1.0, abs_tol=1e-3)

    scan = user.got['scan'][-1]
    assert scan.header.frame_id == 'laser'
    assert len(scan.ranges) > 600 and scan.range_max == pytest.approx(5.6, abs=0.05)
    ahead = round((0.0 - scan.angle_min) / scan.angle_increment)
    assert scan.ranges[ahead] == pytest.approx(WALL_X - START[0], abs=0.1)

    sonar = user.got['sonar'][-1]
    assert sonar.radiation_type == Range.ULTRASOUND and sonar.header.frame_id == 'sonar_link'
    assert sonar.range == pytest.approx(WALL_X - SONAR_X, abs=0.15)

    rt = next(m for m in reversed(user.got['rt_status']) if complete(m))
    assert [t.name for t in rt.tasks][:2] == ['actuator', 'imu']     # priority order
    act = rt.tasks[0]
    assert act.period == pytest.approx(0.01) and act.response_time.samples > 10
    assert act.response_time.max > 0   # measured (its size is the bench's: Table 1)
    assert rt.liu_layland_bound == pytest.approx(6 * (2 ** (1 / 6) - 1))
    assert rt.total_utilization > 0 and rt.rt_link_age < 3.0
    # RT-side counters of every port of the RT process (PORT_STATS), not the bridge's
    ports = {p.label: p for p in rt.ports}
    assert ports.keys() == RT_PORTS.keys()
    assert all(ports[label].port == n for label, n in RT_PORTS.items())
    assert all(p.linked for label, p in ports.items() if label != 'stat')  # rt_stat: on demand
    motor = ports['motor']          # WHEEL_CMD out, ENCODERS + DEVICE_STATUS in, every 10 ms
    assert motor.sent > 100 and motor.received > 100 and motor.malformed == 0
    assert ports['status'].sent > 0 and ports['imu_out'].sent > 100
    assert ports['cmd'].received == 0                            # nobody commanded yet

    diag = next(d for d in reversed(user.got['diagnostics']) if _devices_ok(d))
    names = {s.name: s for s in diag.status}
    for device in ('imu', 'sonar', 'lrf', 'motor', 'led'):
        st = names['m4k_drivers: ' + device]
        values = {kv.key: kv.value for kv in st.values}
        # from the driver's DEVICE_STATUS as forwarded by the RT monitor
        assert values['source'] == 'device_status', (device, values)
        assert (st.level, values['state'], values['last_error']) == (b'\x00', 'active', 'none')
        assert {'faults', 'age_s'} <= values.keys() and 0 <= float(values['age_s']) < 5.0
    assert names['m4k_bridge: rt link'].level == b'\x00'
    keys = {kv.key for kv in names['m4k_rt: task actuator'].values}
    assert {'jitter_max_s', 'deadline_misses', 'cycles'} <= keys


@pytest.mark.parametrize('stack', [{'m4k_bridge': {'ros__parameters': {
    'use_stamped_vel': True}}}], indirect=True)
def test_twist_stamped_mode_drives_too(stack):
    user, _, _ = stack
    x0 = _x(user)
    pub = user.publisher(TwistStamped, 'cmd_vel')
    msg = TwistStamped()
    msg.twist.linear.x = 0.25
    user.spin_for(1.5, each=lambda: pub.publish(msg), period=0.05)
    user.spin_until(lambda: _x(user) - x0 > 0.15, 15, 'the robot to move')


def test_nan_cmd_vel_is_rejected_and_the_robot_does_not_move(stack):
    user, _, tmp_path = stack
    x0 = _x(user)
    pub = user.publisher(Twist, 'cmd_vel')
    bad = Twist()
    bad.linear.x = math.nan

    def rejected():
        for d in reversed(user.got['diagnostics']):
            for s in d.status:
                if s.name == 'm4k_bridge: cmd_vel':
                    return int({kv.key: kv.value for kv in s.values}['rejected_nonfinite'])
        return 0

    user.spin_until(lambda: rejected() >= 10, 15, 'rejected NaN commands in diagnostics',
                    each=lambda: pub.publish(bad), period=0.05)
    user.spin_for(0.5)
    assert abs(_x(user) - x0) < 0.005
    speeds = [o.twist.twist.linear.x for o in user.got['odom'][-20:]]
    assert abs(sum(speeds) / len(speeds)) < STILL / 2, speeds   # only quantization noise
    assert 'non-finite' in (tmp_path / 'bringup.err').read_text()


@TRANSPORTS
def test_bridge_survives_an_rt_core_restart_and_reports_the_gap(stack, request):
    user, proc, tmp_path = stack
    err = (lambda: (tmp_path / 'bringup.err').read_text())  # noqa: E731
    # Ground truth of the transport in use: the RT process maps one region per linked port.
    shm = request.node.callspec.id == 'shm'
    assert (_rt_ring_maps(proc) > 0) == shm

    def pid_of(module):
        pids = [p for p in child_pids(proc.pid) if module in cmdline(p)]
        return pids[0] if pids else None

    user.spin_until(lambda: 'linked to the RT process' in err(), 15, 'the bridge linked')
    core = pid_of('m4k_rt.rt_core')
    assert core is not None
    os.kill(core, signal.SIGKILL)
    try:
        user.spin_until(lambda: 'lost the RT process' in err(), 15, 'the outage log line')
    except AssertionError:
        raise AssertionError(err()[-4000:]) from None
    user.got['odom'].clear()
    user.spin_until(lambda: user.got['odom'] and 'RT process is back after' in err(), 30,
                    'odom again after the rt_core restart')
    assert err().count('lost the RT process') == 1          # logged once per outage

    def link():
        for d in reversed(user.got['diagnostics']):
            for s in d.status:
                if s.name == 'm4k_bridge: rt link':
                    return s
        return None

    user.got['diagnostics'].clear()
    user.spin_until(lambda: link() is not None and link().level == b'\x00', 10, 'link OK')
    values = {kv.key: kv.value for kv in link().values}
    assert values['outages'] == '1' and float(values['last_gap_s']) > 0

    # The reverse: the bridge restarts while the RT process keeps running.
    os.kill(pid_of('m4k_bridge.node'), signal.SIGKILL)
    user.spin_until(lambda: 'bridge restarted' in err(), 15, 'the bridge restart')
    user.got['odom'].clear()
    user.spin_until(lambda: user.got['odom'], 30, 'odom from the restarted bridge')
    assert (_rt_ring_maps(proc) > 0) == shm  # the restarted rt_core, relinked the same way
