"""End to end: kill -9 the stack's processes during a drive; feed the stack bad cmd_vel.

The whole stack runs under ``bringup`` (rt_core + driver_host + bridge, simulated devices);
this test is a ROS client driving it through ``cmd_vel`` and watching ``odom`` and
``diagnostics``, and reads the RT tasks' cycle counters from the monitor's ``stat`` port.

Faults: kill -9 the driver host, the bridge, both, and rt_core, while driving. Expected
(Xenomai XDDP / ros2_control / diff_drive_controller semantics): rt_core keeps running and
its cycle counters never restart; bringup restarts the victim with backoff and reports it; the
restarted process re-links; driving resumes only on a fresh command; with rt_core gone the
driver host's watchdog/link-loss makes the motors safe, so the robot stops, and a restarted
rt_core picks up. Bad input: NaN/inf cmd_vel rejected and counted, huge values clamped,
-0.0 accepted as zero, a wrong message type on the topic ignored. Restart times are printed
(run with -s), not asserted: the VM is noisy.

Two more tests kill one process alone, five times each at seeded random phases of a drive:
the bridge (the RT actuator must brake the simulated robot on its own: judged on the
simulator's ground truth against cmd_vel_timeout + v / max_deceleration + 2 periods from
config/) and the driver host (its motor port re-links within 1 s of serving, on its own log
stamps; the RT side counts every lost peer; rt_core's cycle counters never go back).
"""

import math
import os
import random
import re
import signal
import subprocess
import threading
import time

import pytest
from wsenv import ground_truth, ROOT, stack_env
import yaml

from m4k_bench import recorder
from m4k_bench.soak import children
from m4k_bringup.bringup import bringup_argv
from m4k_rt import channel, config
from m4k_rt.control.params import control_params

rclpy = pytest.importorskip('rclpy')


class Probe:
    """A ROS client of the stack plus a reader of the RT cycle counters (stat port)."""

    def __init__(self, runtime_dir):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from std_msgs.msg import String
        self.Twist = Twist
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node('m4k_fault_probe', context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.cmd = self.node.create_publisher(Twist, 'cmd_vel', 10)
        # Another participant: one participant may not use two types on one topic.
        self.ctx2 = rclpy.Context()
        rclpy.init(context=self.ctx2)
        self.node2 = rclpy.create_node('m4k_fault_probe_wrong_type', context=self.ctx2)
        self.wrong = self.node2.create_publisher(String, 'cmd_vel', 10)
        self.odom = None
        self.odom_count = 0
        self.cmd_diag = {}
        self.node.create_subscription(Odometry, 'odom', self._on_odom, 10)
        self.node.create_subscription(DiagnosticArray, 'diagnostics', self._on_diag, 10)
        self.rec = recorder.Recorder()
        self.stat = channel.NrtLink('stat', runtime_dir, retry_interval=0.1)
        self.cycles_seen = []
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._read_stat, daemon=True)
        self._t.start()

    def _on_odom(self, msg):
        self.odom = msg
        self.odom_count += 1

    def _on_diag(self, msg):
        for s in msg.status:
            if s.name.endswith('cmd_vel'):
                self.cmd_diag = {kv.key: kv.value for kv in s.values}

    def _read_stat(self):
        while not self._stop.is_set():
            data = self.stat.read(0.2)
            if data:
                self.rec.feed(data)
                t = self.rec.tasks.get('actuator')
                if t is not None and (not self.cycles_seen or self.cycles_seen[-1] != t.cycles):
                    self.cycles_seen.append(t.cycles)

    @property
    def v(self):
        return self.odom.twist.twist.linear.x if self.odom else math.nan

    @property
    def x(self):
        return self.odom.pose.pose.position.x if self.odom else math.nan

    def pump(self, seconds, lin=None, ang=0.0):
        """Spin for ``seconds``, publishing cmd_vel at 20 Hz when ``lin`` is given."""
        end = time.monotonic() + seconds
        nxt = 0.0
        while time.monotonic() < end:
            if lin is not None and time.monotonic() >= nxt:
                self.cmd.publish(self.Twist(linear=_vec(lin), angular=_vec(0.0, 0.0, ang)))
                nxt = time.monotonic() + 0.05
            self.ex.spin_once(timeout_sec=0.01)

    def until(self, pred, timeout, what, lin=None):
        """Pump until ``pred()``; return the seconds it took."""
        t0 = time.monotonic()
        while not pred():
            assert time.monotonic() - t0 < timeout, 'timed out after {} s: {}'.format(
                timeout, what)
            self.pump(0.05, lin)
        return time.monotonic() - t0

    def close(self):
        self._stop.set()
        self._t.join(2.0)
        self.stat.close()
        self.ex.shutdown()
        self.node.destroy_node()
        self.node2.destroy_node()
        rclpy.try_shutdown(context=self.ctx)
        rclpy.try_shutdown(context=self.ctx2)


def _start_bringup(procs, tmp_path, overlay, runtime_dir):
    """Start bringup with ``overlay`` in the test's runtime dir; its log in bringup.log."""
    with open(tmp_path / 'bringup.log', 'w') as log:
        return procs.start(bringup_argv(str(overlay)) + ['--status-interval', '1'],
                           env=stack_env(runtime_dir), stdout=log, stderr=subprocess.STDOUT)


def _assert_rt_kept_counting(probe):
    """Assert the RT cycle counter rose at every status across the kills (never restarted)."""
    seen = probe.cycles_seen
    assert len(seen) > KILLS and all(b > a for a, b in zip(seen, seen[1:], strict=False)), \
        'RT cycle counters restarted or stopped: {}'.format(seen)


def _vec(x=0.0, y=0.0, z=0.0):
    from geometry_msgs.msg import Vector3
    return Vector3(x=float(x), y=float(y), z=float(z))


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_stack_survives_kill9_and_bad_cmd_vel(procs, tmp_path, m4k_runtime_dir):
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump({'runtime': {'mlockall': False, 'cpu_dma_latency': False,
                                                   'start_delay_ms': 10}}))
    bu = _start_bringup(procs, tmp_path, overlay, m4k_runtime_dir)
    probe = Probe(m4k_runtime_dir)
    times = {}
    try:
        times['start'] = probe.until(lambda: probe.odom is not None, 60, 'first odom')
        kids = children(bu.pid)
        assert set(kids) == {'rt_core', 'driver_host', 'bridge'}, kids
        rt_pid = kids['rt_core']

        # --- bad input on cmd_vel ------------------------------------------------------------
        from std_msgs.msg import String
        for bad in (math.nan, math.inf, -math.inf):
            probe.cmd.publish(probe.Twist(linear=_vec(bad)))
            probe.cmd.publish(probe.Twist(linear=_vec(0.1), angular=_vec(0, 0, bad)))
        probe.wrong.publish(String(data='forward!'))   # wrong type: never delivered
        probe.until(lambda: int(probe.cmd_diag.get('rejected_nonfinite', 0)) >= 6, 10,
                    'NaN/inf cmd_vel rejected and counted')
        probe.pump(0.5)
        assert abs(probe.v) < 0.02, 'a rejected command moved the robot'
        probe.until(lambda: int(probe.cmd_diag.get('clamped', 0)) > 0, 10,
                    'huge cmd_vel clamped and counted', lin=1e300)
        probe.until(lambda: abs(probe.v) < 0.02, 15, 'stop on -0.0', lin=-0.0)

        # --- drive, then kill -9 the driver host -------------------------------------------
        probe.until(lambda: probe.v > 0.1, 20, 'driving at 0.25 m/s', lin=0.25)
        c0 = probe.cycles_seen[-1]
        for name in ('driver_host', 'bridge'):
            kids = children(bu.pid)
            old = kids[name]
            os.kill(old, signal.SIGKILL)
            t0 = time.monotonic()
            probe.until(lambda n=name, o=old: children(bu.pid).get(n, o) != o, 30,
                        name + ' restarted by bringup', lin=0.25)
            times[name + '_restart'] = time.monotonic() - t0
            n0 = probe.odom_count
            probe.until(lambda n=n0: probe.v > 0.1 and probe.odom_count > n + 5, 30,
                        'driving again after ' + name, lin=0.25)
            times[name + '_driving_again'] = time.monotonic() - t0
            assert children(bu.pid)['rt_core'] == rt_pid, 'rt_core must survive'

        # --- both at once: the restarted pair does not drive on an old command ------------------
        # (Whether the RT actuator brakes on its own is test_bridge_kill_... below: with the
        # driver host killed too, the simulated robot goes with it.)
        kids = children(bu.pid)
        x0 = probe.x
        os.kill(kids['bridge'], signal.SIGKILL)
        os.kill(kids['driver_host'], signal.SIGKILL)       # both at once
        n0 = probe.odom_count
        probe.until(lambda: probe.odom_count > n0 + 5, 60, 'odom from the restarted bridge')
        probe.pump(1.0)   # no cmd_vel: the restarted processes must not drive on an old one
        assert abs(probe.v) < 0.02, 'robot moving without a fresh command: v={}'.format(probe.v)
        # How far it rolled after the kill is a figure of the machine's load (0.25 m/s, 0.5 s
        # timeout, 0.37 m/s^2 ramp: about 0.21 m on a calm one): printed; the brake in time
        # is test_bridge_kill_... on ground truth and `make scenarios` (bridge_killed).
        times['rolled_after_both_killed_m'] = probe.x - x0
        probe.until(lambda: probe.v > 0.1, 30, 'driving on a fresh command', lin=0.25)

        # --- kill -9 rt_core: the robot stops, a restarted rt_core picks up --------------------
        seen = probe.cycles_seen
        assert seen[-1] > c0 and all(b > a for a, b in zip(seen, seen[1:], strict=False)), \
            'RT cycle counters restarted or stopped: {}'.format(seen)
        os.kill(rt_pid, signal.SIGKILL)
        t0 = time.monotonic()
        probe.until(lambda: children(bu.pid).get('rt_core', rt_pid) != rt_pid, 30,
                    'rt_core restarted by bringup', lin=0.25)
        times['rt_core_restart'] = time.monotonic() - t0
        n0 = probe.odom_count
        probe.until(lambda: probe.v > 0.1 and probe.odom_count > n0 + 5, 30,
                    'driving after rt_core restart', lin=0.25)
        times['rt_core_driving_again'] = time.monotonic() - t0
        probe.until(lambda: abs(probe.v) < 0.02, 15, 'brake after the last command')
    finally:
        probe.close()
    bu.send_signal(signal.SIGINT)
    bu.wait(40)
    text = (tmp_path / 'bringup.log').read_text()
    assert bu.returncode == 0, text[-3000:]
    for name in ('driver_host', 'bridge', 'rt_core'):
        assert 'bringup: {} restarted'.format(name) in text, text[-3000:]
    assert 'RT side gone' in text or 'relinking' in text
    print('fault e2e times (s):', {k: round(v, 2) for k, v in times.items()})


def _brake_bound_s(overlay):
    """Return cmd_vel_timeout + v / max_deceleration + 2 actuator periods, from config/."""
    cfg_dir = os.path.join(ROOT, 'config')
    params = control_params(config.load_layered(overlay, cfg_dir).get('control'))
    decel = params.linear.max_deceleration or params.linear.max_acceleration
    period = next(t.period_ns for t in config.load(overlay, cfg_dir).tasks
                  if t.name == 'actuator') / 1e9
    return params.cmd_vel_timeout + DRIVE_V / decel + 2 * period


DRIVE_V = 0.25   # m/s, the paper's experiment speed
KILLS = 5
SEED = 10        # the phases are random but the same every run


def _truth_at_rest_after(probe, runtime_dir, t_ns, timeout):
    """Pump ROS (no command) until the simulator reports the robot at rest at or after
    ``t_ns``; return that report."""
    got = {}

    def reached():
        gt = ground_truth(runtime_dir)
        if gt is not None and gt['t_ns'] >= t_ns and abs(gt['v']) < 0.01:
            got.update(gt)
            return True
        return False
    probe.until(reached, timeout, 'the robot at rest after {} ns'.format(t_ns))
    return got


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_bridge_kill_alone_the_rt_actuator_brakes_the_robot_on_its_own(
        procs, tmp_path, m4k_runtime_dir):
    """Kill -9 only the bridge while cmd_vel flows; the RT actuator stops the robot alone.

    Judged on the simulator's ground truth (wsenv.ground_truth), not on the odometry under
    test: after each kill, with no command sent, the robot comes to rest (|v| < 0.01 m/s) and
    rt_core is the same process (an actuator holding its last command would drive on). How
    long it took is printed against the bound cmd_vel_timeout + v / max_deceleration + 2
    actuator periods from config/ (a figure of the machine's load; `make scenarios` measures
    it with its spread: bridge_killed). The kill lands at a seeded random phase of the drive,
    five times; the RT cycle counters never restart across the kills.
    """
    overlay = tmp_path / 'overlay.yaml'
    # The collision guard off: under load a late sonar/laser reading counts as an obstacle
    # (stale_policy: stop) and would hold the robot, which is not what this test is about.
    overlay.write_text(yaml.safe_dump({'runtime': {'mlockall': False, 'cpu_dma_latency': False,
                                                   'start_delay_ms': 10},
                                       'control': {'guard': {'enabled': False}}}))
    bound_s = _brake_bound_s(str(overlay))
    bu = _start_bringup(procs, tmp_path, overlay, m4k_runtime_dir)
    rng = random.Random(SEED)
    probe = Probe(m4k_runtime_dir)
    stops = []
    try:
        probe.until(lambda: probe.odom is not None, 60, 'first odom')
        rt_pid = children(bu.pid)['rt_core']
        for k in range(KILLS):
            # Forward, then back (the obstacle ahead would stop a forward-only drive): drive
            # until the simulated robot really moves, then on for a random phase.
            lin = DRIVE_V if k % 2 == 0 else -DRIVE_V
            probe.until(lambda: abs((ground_truth(m4k_runtime_dir) or {}).get('v', 0.0)) > 0.2,
                        60, 'simulated robot at speed (kill {})'.format(k), lin=lin)
            probe.pump(rng.uniform(0.0, 1.0), lin=lin)
            # The kill lands while it drives: a stack starved in that phase may have braked on
            # late commands (its fail-safe), so it drives up to speed again first.
            probe.until(lambda: abs((ground_truth(m4k_runtime_dir) or {}).get('v', 0.0)) > 0.2,
                        60, 'simulated robot at speed before kill {}'.format(k), lin=lin)
            old = children(bu.pid)['bridge']
            t_kill = time.monotonic_ns()
            os.kill(old, signal.SIGKILL)
            after = _truth_at_rest_after(probe, m4k_runtime_dir, t_kill, bound_s + 30)
            stops.append((after['t_ns'] - t_kill) / 1e9)
            assert children(bu.pid)['rt_core'] == rt_pid, 'rt_core must survive'
            probe.until(lambda o=old: children(bu.pid).get('bridge', o) != o, 30,
                        'bridge restarted by bringup')
            n0 = probe.odom_count
            probe.until(lambda n=n0: probe.odom_count > n + 5, 60,
                        'odom from the restarted bridge')
        _assert_rt_kept_counting(probe)
    finally:
        probe.close()
    bu.send_signal(signal.SIGINT)
    bu.wait(40)
    text = (tmp_path / 'bringup.log').read_text()
    assert bu.returncode == 0, text[-3000:]
    assert 'bringup: bridge restarted (restart {})'.format(KILLS) in text, text[-3000:]
    print('bridge kill: at rest after the kill (s):', [round(x, 2) for x in stops],
          'bound', round(bound_s, 3))


_LOG_TIME = re.compile(r'^\[driver_host\] (\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) ')


def _host_log_times(text, needle):
    """Return the stamps (s, the driver host's own log clock) of its lines containing needle."""
    out = []
    for line in text.splitlines():
        m = _LOG_TIME.match(line)
        if m and needle in line:
            out.append(time.mktime(time.strptime(m.group(1), '%Y-%m-%d %H:%M:%S'))
                       + int(m.group(2)) / 1000.0)
    return out


@pytest.mark.allow_leaks('fds')  # in-process DDS transports outlive the node
def test_driver_host_kill_alone_relinks_each_restart_and_rt_keeps_counting(
        procs, tmp_path, m4k_runtime_dir):
    """Kill -9 only the driver host, five times at seeded random phases of a drive.

    Each restarted driver host links its motor port to the RT side after it serves and before
    the next one serves (its own log stamps; the delay is printed); the RT side counts every
    lost peer (rt_status motor port peer_restarts, the stack's counter) and is linked again;
    rt_core is never restarted and its actuator cycle counter never goes back; driving resumes
    on fresh commands each time.
    """
    from m4k_msgs.msg import RtStatus
    overlay = tmp_path / 'overlay.yaml'
    overlay.write_text(yaml.safe_dump({'runtime': {'mlockall': False, 'cpu_dma_latency': False,
                                                   'start_delay_ms': 10}}))
    bu = _start_bringup(procs, tmp_path, overlay, m4k_runtime_dir)
    rng = random.Random(SEED + 1)
    probe = Probe(m4k_runtime_dir)
    motor_port = {}

    def on_status(msg):
        for port in msg.ports:
            if port.label == 'motor':
                motor_port.update(linked=port.linked, peer_restarts=port.peer_restarts)
    probe.node.create_subscription(RtStatus, 'rt_status', on_status, 10)
    text = lambda: (tmp_path / 'bringup.log').read_text()  # noqa: E731
    try:
        probe.until(lambda: probe.odom is not None and motor_port.get('linked'), 60,
                    'first odom and a linked motor port')
        rt_pid = children(bu.pid)['rt_core']
        restarts0 = motor_port['peer_restarts']
        for k in range(KILLS):
            lin = DRIVE_V if k % 2 == 0 else -DRIVE_V
            n0 = probe.odom_count
            probe.until(lambda n=n0, s=lin: probe.odom_count > n + 5 and probe.v / s > 0.4, 60,
                        'driving (kill {})'.format(k), lin=lin)
            probe.pump(rng.uniform(0.0, 1.0), lin=lin)
            old = children(bu.pid)['driver_host']
            os.kill(old, signal.SIGKILL)
            probe.until(lambda o=old: children(bu.pid).get('driver_host', o) != o, 30,
                        'driver_host restarted by bringup', lin=lin)
            # the motor's own process says when it serves (m4k_drivers.hostproc)
            probe.until(lambda n=k + 2: len(_host_log_times(text(), 'serving motor@')) >= n
                        and len(_host_log_times(text(), 'motor: linked to the RT side (link 1)'))
                        >= n, 30, 'restarted driver host serving and linked', lin=lin)
            assert children(bu.pid)['rt_core'] == rt_pid, 'rt_core must survive'
        probe.until(lambda: motor_port.get('linked') and motor_port['peer_restarts']
                    >= restarts0 + KILLS, 30, 'the RT side counting every lost motor peer')
        _assert_rt_kept_counting(probe)
    finally:
        probe.close()
    bu.send_signal(signal.SIGINT)
    bu.wait(40)
    log_text = text()
    assert bu.returncode == 0, log_text[-3000:]
    assert 'bringup: driver_host restarted (restart {})'.format(KILLS) in log_text
    serving = _host_log_times(log_text, 'serving motor@')
    linked = _host_log_times(log_text, 'motor: linked to the RT side (link 1)')
    assert len(serving) == len(linked) == KILLS + 1, log_text[-3000:]
    # Each instance links after it serves, and before the next one serves: one link per
    # driver host, in order. How long a re-link takes is a figure of the machine's load,
    # printed here and measured with its spread by `make scenarios` (driver_host_killed).
    events = sorted([(t, 0, 'serving') for t in serving] + [(t, 1, 'linked') for t in linked])
    assert [e for _, _, e in events] == ['serving', 'linked'] * (KILLS + 1), events
    # The first instance waits for rt_core to bind (both start at once): only restarts count.
    relink = [b - a for a, b in zip(serving, linked, strict=True)][1:]
    print('driver host kill: motor re-link after serving (s):', [round(r, 3) for r in relink])
