"""The bridge node in process: own rclpy Context, a fake RT side bound on the XDDP ports."""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, JointState, LaserScan, Range
from std_msgs.msg import ColorRGBA, String
from tf2_msgs.msg import TFMessage
import yaml

from m4k_bridge import params
from m4k_bridge.node import BridgeNode, late_command_s, param_files
from m4k_msgs.msg import RtStatus
from m4k_rt import channel, protocol

PORTS = {'status': 0, 'cmd': 1, 'imu_out': 4, 'led_in': 6, 'sonar_out': 8, 'lrf_out': 10}
pytestmark = [pytest.mark.allow_leaks('fds'),  # FastDDS keeps its sockets for the process
              pytest.mark.e2e]           # ROS nodes: the end-to-end tier


class FakeRt:
    """The RT side of the bridge's ports, driven from the test thread."""

    def __init__(self, runtime_dir):
        self.runtime_dir = runtime_dir
        self.buf = bytearray(4096)
        self.socks = {}
        self.bind()

    def bind(self):
        self.socks = {label: channel.rt_xddp_bind(n, label, runtime_dir=self.runtime_dir)
                      for label, n in PORTS.items()}

    def poll(self):
        for s in self.socks.values():
            s.poll_peer()

    def linked(self):
        return all(s.connected for s in self.socks.values())

    def send(self, label, kind, *fields, seq=0, stamp=None):
        stamp = time.monotonic_ns() if stamp is None else stamp
        return self.socks[label].send(protocol.encode(kind, seq, stamp, *fields))

    def recv_all(self, label):
        out = []
        while (n := self.socks[label].recv_into(self.buf)) > 0:
            out.append(protocol.decode(bytes(self.buf[:n])))
        return out

    def close(self):
        for s in self.socks.values():
            s.close()
        self.socks = {}


class Harness:
    def __init__(self, runtime_dir, overrides=(), namespace=''):
        self.rt = FakeRt(runtime_dir)
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.bridge = None
        self.bridge = BridgeNode(context=self.context, namespace=namespace, parameter_overrides=[
            Parameter('runtime_dir', value=runtime_dir),
            Parameter('diagnostics_period', value=0.2),
            Parameter('rt_status_period', value=0.2), *overrides])
        self.peer = rclpy.create_node('bridge_test_peer', context=self.context)
        self.executor.add_node(self.bridge)
        self.executor.add_node(self.peer)
        self.got = {}

    def collect(self, msg_type, topic, qos=10):
        box = self.got.setdefault(topic, [])
        self.peer.create_subscription(msg_type, topic, box.append, qos)
        return box

    def spin_until(self, predicate, timeout=10.0, each=None):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.rt.poll()
            if each is not None:
                each()
            self.executor.spin_once(timeout_sec=0.02)
            if predicate():
                return True
        return False

    def close(self):
        if self.bridge is not None:
            self.bridge.destroy_node()
        self.peer.destroy_node()
        self.executor.shutdown()
        rclpy.try_shutdown(context=self.context)
        self.rt.close()


@pytest.fixture
def harness(m4k_runtime_dir):
    h = Harness(m4k_runtime_dir)
    try:
        assert h.spin_until(h.rt.linked), 'bridge did not link all ports'
        yield h
    finally:
        h.close()


def test_cmd_vel_is_forwarded_clamped_and_nan_rejected(harness):
    pub = harness.peer.create_publisher(Twist, 'cmd_vel', 10)
    got = []

    def drain():
        got.extend(harness.rt.recv_all('cmd'))

    msg = Twist()
    msg.linear.x, msg.angular.z = 0.25, 0.1
    assert harness.spin_until(lambda: got, each=lambda: (pub.publish(msg), drain()))
    header, cmd = got[-1]
    assert header.kind == protocol.Kind.VELOCITY_CMD
    assert cmd == protocol.VelocityCmd(0.25, 0.1)

    fast = Twist()
    fast.linear.x = 9.0
    got.clear()
    assert harness.spin_until(lambda: got and got[-1][1].linear_x == 2.0,
                              each=lambda: (pub.publish(fast), drain()))
    assert harness.bridge.health.counters['cmd_vel_clamped'] >= 1
    assert all(c.linear_x in (0.25, 2.0) for _, c in got)  # clamped, never 9

    bad = Twist()
    bad.linear.x = math.nan
    got.clear()
    assert harness.spin_until(
        lambda: harness.bridge.health.counters['cmd_vel_rejected_nonfinite'] >= 3,
        each=lambda: (pub.publish(bad), drain()))
    drain()
    # Only clamped commands still in flight arrive; nothing of the NaN ones is forwarded.
    assert all(c.linear_x == 2.0 for _, c in got), got


def test_a_cmd_vel_that_waited_past_the_timeout_in_the_bridge_is_dropped(harness):
    # A bridge that runs its callbacks late (starved, stalled) must not forward commands
    # that arrived longer than cmd_vel_timeout ago: the RT actuator has braked on their
    # absence, and after a link drop their sender cannot follow them up.
    timeout = harness.bridge.p['cmd_vel_timeout']
    pub = harness.peer.create_publisher(Twist, 'cmd_vel', 10)
    assert harness.spin_until(lambda: pub.get_subscription_count() >= 1)
    got = []

    def drain():
        got.extend(c for h, c in harness.rt.recv_all('cmd')
                   if h.kind == protocol.Kind.VELOCITY_CMD)
    old = Twist()
    old.linear.x = 0.3
    for _ in range(3):
        pub.publish(old)         # taken in by the middleware now, run by nobody yet
    time.sleep(timeout + 0.5)
    drain()
    got.clear()
    assert harness.spin_until(lambda: harness.bridge.health.counters['cmd_vel_late'] >= 1,
                              each=drain)
    harness.spin_until(lambda: False, timeout=0.5, each=drain)
    assert not any(c.linear_x == 0.3 for c in got), got
    # fresh commands still drive
    fresh = Twist()
    fresh.linear.x = 0.25
    assert harness.spin_until(lambda: any(c.linear_x == 0.25 for c in got),
                              each=lambda: (pub.publish(fresh), drain()))


def test_late_command_s_judges_the_wait_on_this_machines_clock():
    assert late_command_s(0, 10**10, 0.5) is None            # no reception time: not judged
    assert late_command_s(10**9, 10**10, 0.0) is None        # timeout off
    assert late_command_s(10**10 - 4 * 10**8, 10**10, 0.5) is None
    assert late_command_s(10**10 - 6 * 10**8, 10**10, 0.5) == pytest.approx(0.6)


def test_shutdown_sends_a_zero_command(m4k_runtime_dir):
    h = Harness(m4k_runtime_dir)
    try:
        assert h.spin_until(h.rt.linked)
        h.bridge.destroy_node()
        h.bridge = None
        cmds = [c for hdr, c in h.rt.recv_all('cmd') if hdr.kind == protocol.Kind.VELOCITY_CMD]
        assert cmds and cmds[-1] == protocol.VelocityCmd(0.0, 0.0)
    finally:
        h.close()


def test_led_colour_is_forwarded_and_alpha_zero_releases(harness):
    pub = harness.peer.create_publisher(ColorRGBA, 'led', 10)
    got = []
    red = ColorRGBA(r=1.0, g=0.0, b=0.0, a=1.0)
    assert harness.spin_until(lambda: got, each=lambda: (
        pub.publish(red), got.extend(harness.rt.recv_all('led_in'))))
    assert got[-1][1] == protocol.Led(255, 0, 0, 255, 1)
    got.clear()
    off = ColorRGBA(r=1.0, g=1.0, b=1.0, a=0.0)
    release = protocol.Led(0, 0, 0, 0, 0)
    assert harness.spin_until(lambda: got and got[-1][1] == release, each=lambda: (
        pub.publish(off), got.extend(harness.rt.recv_all('led_in'))))
    assert {c for _, c in got} <= {release, protocol.Led(255, 0, 0, 255, 1)}


def test_datagrams_become_odom_imu_scan_and_sonar(harness):
    odom = harness.collect(Odometry, 'odom')
    imu = harness.collect(Imu, 'imu', qos_profile_sensor_data)
    scan = harness.collect(LaserScan, 'scan', qos_profile_sensor_data)
    sonar = harness.collect(Range, 'sonar', qos_profile_sensor_data)
    rt = harness.rt

    def feed():
        rt.send('cmd', protocol.Kind.ODOMETRY, 0.5, 0.1, 0.2, 0.25, 0.0, 2.4, 2.5, 7.0, 7.5, 0)
        rt.send('imu_out', protocol.Kind.IMU, 0, 0, 0, 1, 0, 0, 0.05, 0, 0, 9.81, 0)
        rt.send('lrf_out', protocol.Kind.LASER_SCAN, -2.09, 0.00614, 0.02, 5.6, 0.1, 1e-4, 7,
                (1500,) * 10 + (0,))
        rt.send('sonar_out', protocol.Kind.SONAR, 1.4, protocol.SONAR_OK)

    assert harness.spin_until(lambda: odom and imu and scan and sonar, each=feed)
    o = odom[-1]
    assert (o.header.frame_id, o.child_frame_id) == ('odom', 'base_footprint')
    assert o.pose.pose.position.x == 0.5 and o.twist.twist.linear.x == 0.25
    assert o.pose.covariance[0] == pytest.approx(0.001)
    assert imu[-1].header.frame_id == 'imu_link' and imu[-1].linear_acceleration.z == 9.81
    s = scan[-1]
    assert len(s.ranges) == 11 and s.ranges[0] == pytest.approx(1.5) and math.isinf(s.ranges[10])
    assert s.angle_max == pytest.approx(-2.09 + 10 * 0.00614, rel=1e-5)
    assert sonar[-1].range == pytest.approx(1.4) and sonar[-1].radiation_type == Range.ULTRASOUND


def test_malformed_datagram_is_counted_not_published(harness):
    odom = harness.collect(Odometry, 'odom')
    harness.rt.socks['cmd'].send(b'MK-garbage-datagram')
    assert harness.spin_until(lambda: harness.bridge.health.counters['malformed_cmd'] >= 1)
    assert not odom


def _stats_batch(rt, name, index, prio, period_ns, start_cycle, n, response_ns):
    t0 = 1_000_000_000
    samples = [(t0 + i * period_ns, t0 + i * period_ns + 50_000,
                t0 + i * period_ns + 50_000 + response_ns, 1)
               for i in range(start_cycle, start_cycle + n)]
    rt.send('status', protocol.Kind.TASK_STATS, name, index, prio, -1, period_ns,
            start_cycle + n, start_cycle + n, 0, 0, 0, samples)


def test_task_stats_become_rt_status_and_diagnostics(harness):
    status = harness.collect(RtStatus, 'rt_status')
    diags = harness.collect(DiagnosticArray, 'diagnostics')
    rt = harness.rt
    state = {'cycle': 0}

    def feed():
        c = state['cycle']
        _stats_batch(rt, 'actuator', 0, 90, 10_000_000, c, 20, 1_000_000)
        _stats_batch(rt, 'lrf', 4, 70, 200_000_000, c, 20, 20_000_000)
        rt.send('status', protocol.Kind.PORT_STATS, 'cmd', 1, 1, c, 2 * c, 0, 1, 0, 3, 1)
        rt.send('status', protocol.Kind.PORT_STATS, 'status', 0, 1, c, 0, 0, 0, 0, 0, 0)
        rt.send('status', protocol.Kind.RT_STATUS, 1, 1, 0, 1, 0, 2, c)
        rt.send('cmd', protocol.Kind.ODOMETRY, 0, 0, 0, 0, 0, 0, 0, 0, 0, protocol.ODOM_GUARD)
        state['cycle'] = c + 20

    def whole(m):
        # a whole batch: the tasks, the ports and the odometry's guard flag come one datagram
        # each (two ports), and an rt_status built mid-batch lacks the rest
        return len(m.tasks) == 2 and len(m.ports) == 2 and m.collision_guard_active

    def ready():
        return any(whole(m) for m in status) and any(
            any(s.name == 'm4k_rt: task actuator' for s in d.status) and any(
                s.name == 'm4k_bridge: rt link' and s.level == b'\x00' for s in d.status)
            for d in diags)

    assert harness.spin_until(ready, each=feed)
    m = [m for m in status if whole(m)][-1]
    assert [t.name for t in m.tasks] == ['actuator', 'lrf']  # highest priority first
    act = m.tasks[0]
    assert act.period == pytest.approx(0.01) and act.priority == 90
    assert act.response_time.max == pytest.approx(0.001)
    assert act.release_latency.avg == pytest.approx(50e-6)
    assert act.utilization == pytest.approx(0.1)
    assert m.total_utilization == pytest.approx(0.2)
    assert m.liu_layland_bound == pytest.approx(2 * (2 ** 0.5 - 1))
    assert m.schedulable and m.policy == RtStatus.POLICY_FIFO and m.memory_locked
    assert m.collision_guard_active and not m.degraded
    # the RT side's counters from PORT_STATS, by port number (not the bridge's own)
    assert [(p.port, p.label) for p in m.ports] == [(0, 'status'), (1, 'cmd')]
    cmd = m.ports[1]
    assert cmd.linked and cmd.received == 2 * cmd.sent and cmd.malformed == 3
    assert (cmd.dropped_full, cmd.peer_restarts) == (1, 1)
    d = [d for d in diags if any(s.name == 'm4k_bridge: rt link' and s.level == b'\x00'
                                 for s in d.status)][-1]
    task = next(s for s in d.status if s.name == 'm4k_rt: task actuator')
    assert task.level == b'\x00'
    assert {kv.key: kv.value for kv in task.values}['priority'] == '90'
    link = next(s for s in d.status if s.name == 'm4k_bridge: rt link')
    assert link.level == b'\x00'


def _statuses(diag):
    return {s.name: (s.level, s.message, {kv.key: kv.value for kv in s.values})
            for s in diag.status}


def test_device_status_from_the_monitor_drives_device_diagnostics(harness):
    diags = harness.collect(DiagnosticArray, 'diagnostics')
    rt = harness.rt

    def feed():
        now = time.monotonic_ns()
        # as the RT monitor forwards them: stamped with when the RT task got the report
        rt.send('status', protocol.Kind.DEVICE_STATUS, 'lrf', 5, protocol.LEVEL_ERROR, 7, 4,
                stamp=now - 2_000_000_000)
        rt.send('status', protocol.Kind.DEVICE_STATUS, 'imu', 3, protocol.LEVEL_STALE, 0, 0,
                stamp=now - 4_000_000_000)
        rt.send('sonar_out', protocol.Kind.SONAR, 1.4, protocol.SONAR_OK)

    def whole(st):
        # the lrf and imu reports and the sonar reading are three datagrams: a diagnostics
        # built between them judges the others by data arrival
        return all(d in st and st[d][2].get('source') == 'device_status'
                   for d in ('m4k_drivers: lrf', 'm4k_drivers: imu')) and \
            'm4k_drivers: sonar' in st and st['m4k_drivers: sonar'][0] == b'\x00' and \
            st['m4k_bridge: rt link'][0] == b'\x00'

    assert harness.spin_until(lambda: any(whole(st) for st in map(_statuses, diags)),
                              each=feed)
    st = [x for x in map(_statuses, diags) if whole(x)][-1]
    level, msg, values = st['m4k_drivers: lrf']
    assert level == b'\x02' and 'io' in msg
    assert (values['state'], values['faults'], values['last_error']) == ('error', '7', 'io')
    assert 2.0 <= float(values['age_s']) < 10.0
    level, msg, values = st['m4k_drivers: imu']
    assert level == b'\x03' and values['state'] == 'active'
    assert float(values['age_s']) >= 4.0
    # no DEVICE_STATUS for the sonar: judged by data arrival, as before
    level, _, values = st['m4k_drivers: sonar']
    assert level == b'\x00' and values['source'] == 'data_arrival'


def test_host_drops_from_the_monitor_become_one_diagnostic_per_device(harness):
    diags = harness.collect(DiagnosticArray, 'diagnostics')
    rt = harness.rt
    t0 = time.monotonic_ns()
    sent = {'n': 0}

    def feed():
        # As the RT monitor forwards them once a second: the motor's host dropped three stale
        # commands between its first two reports; the LED's never dropped anything.
        if sent['n'] < 2:
            now = time.monotonic_ns()
            stale = 0 if sent['n'] == 0 else 3
            rt.send('status', protocol.Kind.HOST_DROPS, 'motor', 100 + 50 * sent['n'], stale,
                    0, 0, 0, 0, 0, 0, stamp=now)
            rt.send('status', protocol.Kind.HOST_DROPS, 'led', 10, 0, 0, 0, 0, 0, 0, 0,
                    stamp=now)
            sent['n'] += 1

    def ready():
        return any(_statuses(d).get('m4k_drivers: motor host drops', (b'',))[0] == b'\x01'
                   for d in diags)

    assert harness.spin_until(ready, each=feed)
    st = [_statuses(d) for d in diags if _statuses(d).get(
        'm4k_drivers: motor host drops', (b'',))[0] == b'\x01'][-1]
    level, msg, values = st['m4k_drivers: motor host drops']
    assert msg.startswith('3 dropped in the last') and msg.endswith(': stale_host 3')
    assert {k: values[k] for k in ('served', *protocol.HOST_DROP_REASONS, 'window_drops')} == {
        'served': '150', 'stale_host': '3', 'stale_device': '0', 'malformed': '0',
        'unexpected': '0', 'inactive': '0', 'encode': '0', 'reply_lost': '0',
        'window_drops': '3'}
    assert 0.0 < float(values['window_drops_per_s'])
    assert float(values['age_s']) <= (time.monotonic_ns() - t0) * 1e-9
    level, msg, values = st['m4k_drivers: led host drops']
    assert level == b'\x00' and values['window_drops'] == '0' and values['served'] == '10'
    assert not harness.bridge.health.counters.get('unexpected_status')


def test_rt_restart_is_survived_and_reported(harness):
    odom = harness.collect(Odometry, 'odom')
    rt = harness.rt
    def feed():
        return (rt.send('cmd', protocol.Kind.ODOMETRY, 1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
    assert harness.spin_until(lambda: harness.bridge.health.rt_alive, each=feed)
    harness.bridge.set_parameters([Parameter('rt_stale_timeout', value=0.3)])
    rt.close()
    assert harness.spin_until(lambda: not harness.bridge.health.rt_alive)
    assert harness.bridge.health.outages == 1
    rt.bind()
    odom.clear()
    assert harness.spin_until(lambda: rt.linked() and odom, each=feed)
    assert harness.spin_until(lambda: harness.bridge.health.rt_alive, each=feed)
    assert harness.bridge.health.last_gap_s > 0
    assert all(p.lost >= 1 for p in harness.bridge._pumps.values())


def test_runtime_parameter_change_is_validated(harness):
    ok = harness.bridge.set_parameters([Parameter('max_linear_velocity', value=1.0)])
    assert ok[0].successful and harness.bridge.p['max_linear_velocity'] == 1.0
    bad = harness.bridge.set_parameters([Parameter('max_linear_velocity', value=-1.0)])
    assert not bad[0].successful
    cross = harness.bridge.set_parameters([Parameter('sonar_max_range', value=0.01)])
    assert not cross[0].successful and 'sonar_min_range' in cross[0].reason
    ro = harness.bridge.set_parameters([Parameter('ports.cmd', value='other')])
    assert not ro[0].successful


def test_stamped_mode_drives_too(m4k_runtime_dir):
    h = Harness(m4k_runtime_dir, [Parameter('use_stamped_vel', value=True)])
    try:
        assert h.spin_until(h.rt.linked)
        pub = h.peer.create_publisher(TwistStamped, 'cmd_vel', 10)
        msg = TwistStamped()
        msg.twist.linear.x = 0.3
        got = []
        assert h.spin_until(lambda: got, each=lambda: (pub.publish(msg),
                                                       got.extend(h.rt.recv_all('cmd'))))
        assert got[-1][1].linear_x == pytest.approx(0.3)
    finally:
        h.close()


@pytest.mark.parametrize('name, value', [
    ('cmd_vel_timeout', -2.0), ('odom_frame', ''), ('odom_pose_covariance_diagonal', [1.0, 2.0]),
    ('robot_description', '<robot name="x"><link name="base_link"/></robot>')])
def test_configure_fails_with_bad_parameter(m4k_runtime_dir, name, value):
    context = rclpy.context.Context()
    rclpy.init(context=context)
    try:
        with pytest.raises(params.ParamError) as info:
            BridgeNode(context=context, parameter_overrides=[Parameter(name, value=value)])
        assert info.value.name == name
    finally:
        rclpy.try_shutdown(context=context)


def test_param_files_are_found_on_the_command_line():
    argv = ['bridge', '--ros-args', '--params-file', 'a.yaml', '-p', 'x:=1',
            '--params-file', 'b.yaml']
    assert param_files(argv) == ['a.yaml', 'b.yaml']


# --- robot state: joint_states, tf, tf_static, robot_description (m4k_bridge.tf) ----------

_LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.mark.parametrize('publish_tf, robot_state', [(True, True), (False, True),
                                                      (True, False)])
def test_tf_switches_select_who_publishes_which_transform(m4k_runtime_dir, publish_tf,
                                                          robot_state):
    h = Harness(m4k_runtime_dir, [Parameter('publish_tf', value=publish_tf),
                                  Parameter('publish_robot_state', value=robot_state)])
    try:
        tf = h.collect(TFMessage, 'tf', 100)
        static = h.collect(TFMessage, 'tf_static', _LATCHED)
        joints = h.collect(JointState, 'joint_states')
        desc = h.collect(String, 'robot_description', _LATCHED)
        assert h.spin_until(h.rt.linked)
        feed = lambda: h.rt.send('cmd', protocol.Kind.ODOMETRY, 0.5, 0.1, 0.2, 0.25, 0.0,  # noqa
                                 2.4, 2.5, math.pi, -1.0, 0)
        assert h.spin_until(lambda: joints and (desc or not robot_state)
                            and (tf or not (publish_tf or robot_state))
                            and (static or not robot_state), each=feed)
        js = joints[-1]
        assert list(js.name) == ['left_wheel_joint', 'right_wheel_joint']
        assert list(js.position) == [math.pi, -1.0] and list(js.velocity) == [2.4, 2.5]
        pairs = {(t.header.frame_id, t.child_frame_id): t for m in tf for t in m.transforms}
        assert (('odom', 'base_footprint') in pairs) == publish_tf
        assert (('base_link', 'left_wheel_link') in pairs) == robot_state
        if robot_state:   # half a turn about the axle (y): quaternion (0, 1, 0, 0)
            q = pairs[('base_link', 'left_wheel_link')].transform.rotation
            assert (q.x, q.y, q.z, q.w) == pytest.approx((0.0, 1.0, 0.0, 0.0), abs=1e-9)
            assert {t.child_frame_id for m in static for t in m.transforms} == {
                'base_link', 'laser', 'imu_link', 'sonar_link', 'front_caster_link',
                'rear_caster_link'}
            assert '<robot name="m4k">' in desc[-1].data
        else:
            assert not h.peer.get_publishers_info_by_topic('/tf_static')
            # robot_state_publisher publishes the description then: one publisher, not two.
            assert not h.peer.get_publishers_info_by_topic('/robot_description')
    finally:
        h.close()


# --- the ROS contract for Nav2 / slam_toolbox / RViz (issue 21) -----------------------------

def _odometry(h, flags=0):
    return lambda: h.rt.send('cmd', protocol.Kind.ODOMETRY, 0.5, 0.1, 0.2, 0.25, 0.0,
                             2.4, 2.5, 0.0, 0.0, flags)


@pytest.mark.parametrize('tf_namespaced', [False, True])
def test_tf_and_diagnostics_stay_absolute_under_a_namespace(m4k_runtime_dir, tf_namespaced):
    h = Harness(m4k_runtime_dir, [Parameter('tf_namespaced', value=tf_namespaced),
                                  Parameter('frame_prefix', value='r1/')], namespace='r1')
    try:
        where = '/r1/' if tf_namespaced else '/'
        tf = h.collect(TFMessage, where + 'tf', 100)
        static = h.collect(TFMessage, where + 'tf_static', _LATCHED)
        diag = h.collect(DiagnosticArray, '/diagnostics')
        odom = h.collect(Odometry, '/r1/odom')
        assert h.spin_until(h.rt.linked)
        assert h.spin_until(lambda: tf and static and diag and odom, each=_odometry(h))
        other = '/tf' if tf_namespaced else '/r1/tf'
        assert not h.peer.get_publishers_info_by_topic(other)
        parents = {t.child_frame_id: t.header.frame_id
                   for m in static + tf for t in m.transforms}
        assert parents['r1/base_footprint'] == 'r1/odom'
        assert parents['r1/base_link'] == 'r1/base_footprint'
        assert parents['r1/laser'] == 'r1/base_link'
        o = odom[-1]
        assert (o.header.frame_id, o.child_frame_id) == ('r1/odom', 'r1/base_footprint')
    finally:
        h.close()


def test_frames_changed_at_run_time_reach_odom_and_tf(harness):
    h = harness
    tf = h.collect(TFMessage, '/tf', 100)
    odom = h.collect(Odometry, 'odom')
    res = h.bridge.set_parameters([Parameter('odom_frame', value='world_odom'),
                                   Parameter('footprint_frame', value='')])
    assert all(r.successful for r in res)
    assert h.spin_until(lambda: odom and any(
        t.header.frame_id == 'world_odom' for m in tf for t in m.transforms), each=_odometry(h))
    pairs = {(t.header.frame_id, t.child_frame_id) for t in tf[-1].transforms}
    assert ('world_odom', 'base_link') in pairs
    assert (odom[-1].header.frame_id, odom[-1].child_frame_id) == ('world_odom', 'base_link')


@pytest.mark.parametrize('no_echo', ['positive_infinity', 'max_range'])
def test_sonar_never_publishes_nan(m4k_runtime_dir, no_echo):
    h = Harness(m4k_runtime_dir, [Parameter('sonar_no_echo', value=no_echo)])
    try:
        sonar = h.collect(Range, 'sonar', qos_profile_sensor_data)
        assert h.spin_until(h.rt.linked)

        def feed():
            for status in (protocol.SONAR_TIMEOUT, protocol.SONAR_FAULT, protocol.SONAR_NO_ECHO):
                h.rt.send('sonar_out', protocol.Kind.SONAR, 0.0, status)
        assert h.spin_until(lambda: len(sonar) >= 3 and
                            h.bridge.health.counters['sonar_dropped'] >= 6, each=feed)
        assert not any(math.isnan(m.range) for m in sonar)
        want = math.inf if no_echo == 'positive_infinity' else sonar[-1].max_range
        assert all(m.range == want for m in sonar)
    finally:
        h.close()


def test_a_cmd_vel_publisher_of_the_other_type_is_reported(harness):
    h = harness
    diag = h.collect(DiagnosticArray, '/diagnostics')
    # Another participant (a laptop's Nav2): one participant cannot hold both types.
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    laptop = rclpy.create_node('laptop', context=ctx)
    pub = laptop.create_publisher(TwistStamped, 'cmd_vel', 10)

    def cmd_status():
        for arr in diag[-1:]:
            for st in arr.status:
                if st.name == 'm4k_bridge: cmd_vel':
                    return st
        return None
    assert h.spin_until(lambda: cmd_status() is not None
                        and cmd_status().level == b'\x01', timeout=15.0)
    st = cmd_status()
    assert 'geometry_msgs/msg/TwistStamped' in st.message
    assert 'geometry_msgs/msg/Twist subscribed' in st.message
    laptop.destroy_publisher(pub)
    laptop.destroy_node()
    rclpy.try_shutdown(context=ctx)
    diag.clear()
    assert h.spin_until(lambda: cmd_status() is not None
                        and cmd_status().level == b'\x00', timeout=15.0)


def test_enable_stamped_cmd_vel_drives(m4k_runtime_dir):
    h = Harness(m4k_runtime_dir, [Parameter('enable_stamped_cmd_vel', value=True)])
    try:
        assert h.spin_until(h.rt.linked)
        pub = h.peer.create_publisher(TwistStamped, 'cmd_vel', 10)
        msg = TwistStamped()
        msg.twist.linear.x = 0.2
        got = []
        assert h.spin_until(lambda: got, each=lambda: (pub.publish(msg),
                                                       got.extend(h.rt.recv_all('cmd'))))
        assert got[-1][1].linear_x == pytest.approx(0.2)
    finally:
        h.close()


@pytest.mark.parametrize('msg_type', [TwistStamped, Twist])
def test_enable_stamped_cmd_vel_auto_takes_the_first_publishers_type_and_drives(
        m4k_runtime_dir, tmp_path, msg_type):
    h = Harness(m4k_runtime_dir, [Parameter('enable_stamped_cmd_vel', value='auto'),
                                  Parameter('flight_recorder.directory', value=str(tmp_path))])
    # the publisher in another participant (a laptop): one participant cannot hold both types
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx)
    laptop = rclpy.create_node('laptop', context=ctx)
    try:
        assert h.spin_until(h.rt.linked)
        pub = laptop.create_publisher(msg_type, 'cmd_vel', 10)
        msg = msg_type()
        (msg.twist if msg_type is TwistStamped else msg).linear.x = 0.2
        got = []
        assert h.spin_until(lambda: got, timeout=15.0, each=lambda: (
            pub.publish(msg), got.extend(h.rt.recv_all('cmd'))))
        assert got[-1][1].linear_x == pytest.approx(0.2)

        def bridge_types():          # the graph cache drops a destroyed subscription shortly after
            return [i.topic_type for i in h.bridge.get_subscriptions_info_by_topic('/cmd_vel')
                    if i.node_name == 'm4k_bridge']
        h.spin_until(lambda: len(bridge_types()) == 1, timeout=5.0)
        assert bridge_types() == ['geometry_msgs/msg/' + msg_type.__name__]
        assert h.bridge.p['enable_stamped_cmd_vel'] == 'auto'
        # One subscription per input topic: the flight recorder is fed by the bridge's own.
        assert [i.node_name for i in h.bridge.get_subscriptions_info_by_topic(
            '/e_stop')].count('m4k_bridge') == 1
        # ... and keeps cmd_vel as the bridge received it, with the type subscribed.
        flight = h.bridge._flight
        assert flight.trigger('e_stop', 'test')
        flight.close()                          # writes the queued dump now
        path = flight.dumper.written[-1]
        with open(os.path.join(path, 'metadata.yaml'), encoding='utf-8') as f:
            meta = yaml.safe_load(f)['rosbag2_bagfile_information']
        listed = {t['topic_metadata']['name']: (t['topic_metadata']['type'], t['message_count'])
                  for t in meta['topics_with_message_count']}
        kind, count = listed['/cmd_vel']
        assert kind == 'geometry_msgs/msg/' + msg_type.__name__ and count >= 1
    finally:
        laptop.destroy_node()
        rclpy.try_shutdown(context=ctx)
        h.close()


def test_enable_stamped_cmd_vel_refuses_other_words():
    assert params.validate('enable_stamped_cmd_vel', 'yes') == \
        "expected true, false or auto, got 'yes'"
    assert params.validate('enable_stamped_cmd_vel', 'auto') is None
    assert params.validate('enable_stamped_cmd_vel', True) is None


def test_e_stop_service_answers_once_the_rt_latch_confirms_and_state_is_latched(harness):
    from std_msgs.msg import Bool
    from std_srvs.srv import SetBool
    h = harness
    latch = {'engaged': False}

    def rt_side():                    # the RT actuator: latch on E_STOP, report in ODOMETRY
        for hdr, msg in h.rt.recv_all('cmd'):
            if hdr.kind == protocol.Kind.E_STOP:
                latch['engaged'] = bool(msg.engage)
        _odometry(h, protocol.ODOM_E_STOP if latch['engaged'] else 0)()
    client = h.peer.create_client(SetBool, '/m4k_bridge/e_stop')
    assert h.spin_until(client.service_is_ready)
    fut = client.call_async(SetBool.Request(data=True))
    assert h.spin_until(fut.done, each=rt_side)
    assert fut.result().success and latch['engaged']
    # A late subscriber (transient local) gets the state at once.
    state = h.collect(Bool, 'e_stop_state', _LATCHED)
    assert h.spin_until(lambda: state, each=rt_side)
    assert state[-1].data is True
    fut = client.call_async(SetBool.Request(data=False))
    assert h.spin_until(fut.done, each=rt_side)
    assert fut.result().success and h.spin_until(lambda: state[-1].data is False,
                                                 each=rt_side)
    # No RT answer: success=false after e_stop_timeout, never a hang.
    fut = client.call_async(SetBool.Request(data=True))
    assert h.spin_until(fut.done, timeout=15.0, each=_odometry(h, 0))
    assert not fut.result().success and 'did not report' in fut.result().message


def test_set_pose_is_answered_with_the_pose_the_rt_side_acknowledges(harness):
    from m4k_msgs.srv import SetPose
    h = harness

    def rt_side():
        for hdr, msg in h.rt.recv_all('cmd'):
            if hdr.kind == protocol.Kind.SET_POSE:
                h.rt.send('cmd', protocol.Kind.SET_POSE, msg.request_id, msg.x, msg.y, msg.yaw)
    client = h.peer.create_client(SetPose, '/m4k_bridge/set_pose')
    assert h.spin_until(client.service_is_ready)
    fut = client.call_async(SetPose.Request(x=1.5, y=-2.0, yaw=0.5))
    assert h.spin_until(fut.done, each=rt_side)
    assert fut.result().success and '(1.500, -2.000, 0.500)' in fut.result().message
    fut = client.call_async(SetPose.Request(x=math.nan, y=0.0, yaw=0.0))
    assert h.spin_until(fut.done)
    assert not fut.result().success and 'finite' in fut.result().message


def test_applied_velocity_becomes_cmd_vel_out(harness):
    h = harness
    out = h.collect(TwistStamped, 'cmd_vel_out')
    assert h.spin_until(lambda: out, each=lambda: h.rt.send(
        'cmd', protocol.Kind.APPLIED_VELOCITY, 0.125, -0.25))
    assert (out[-1].twist.linear.x, out[-1].twist.angular.z) == (0.125, -0.25)
    assert out[-1].header.frame_id == 'base_footprint'


def test_a_latched_faults_supervision_trace_goes_from_the_monitor_to_a_file(m4k_runtime_dir,
                                                                            tmp_path):
    # The whole path: the supervision's ring frozen at a latch, the RT monitor's FAULT_TRACE
    # rows on `status`, the bridge's file beside the flight recorder's dumps -- once a fault.
    from m4k_rt import config, sched
    from m4k_rt.control.trace import SupervisionTrace
    from m4k_rt.rt_core import SharedState, StatsShipper
    from m4k_rt.tasks.state import RobotState
    h = Harness(m4k_runtime_dir, [Parameter('flight_recorder.directory', value=str(tmp_path))])
    try:
        assert h.spin_until(h.rt.linked)
        robot = RobotState()
        robot.fault_trace = trace = SupervisionTrace()
        for n in range(100):
            trace.record(1_000_000_000 + n * 10_000_000, int(protocol.TraceFlag.ENCODERS),
                         (4.9, 4.9, 4.9 - 0.1 * n, 4.9, 0.3, 0.3, 0.01 * n, 0.05 * n,
                          0.0, 0.0, 0.0, -1.0, -1.0), [0.0] * 10)
        trace.freeze(1, int(protocol.FaultCause.LEFT_WRONG_WAY))
        shared = SharedState(config.load(), sched.Hardening(), tasks=[])
        shared.robot = robot
        ship = StatsShipper(shared, [(h.rt.socks['status'], False)])

        def files():
            return sorted(tmp_path.glob('fault_trace_*.csv'))
        ship.ship()
        assert h.spin_until(lambda: files(), timeout=10.0)
        ship.ship()                                       # shipped once per fault
        h.spin_until(lambda: len(files()) > 1, timeout=1.0)
        (path,) = files()
        lines = path.read_text().splitlines()
        assert lines[0].split(',')[:3] == ['t_ms', 'sp_left', 'sp_right']
        assert len(lines) == 1 + 64                        # the ring's newest 64 cycles
        first, last = lines[1].split(','), lines[-1].split(',')
        assert first[0] == '-630.0' and last[0] == '0.0' and last[-1] == 'encoders'
        assert float(last[3]) == pytest.approx(4.9 - 9.9)  # meas_left of the latching cycle
        assert path.name.endswith('_1.csv')
    finally:
        h.close()
