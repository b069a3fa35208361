"""Run one scenario on the whole stack and judge it on the simulator's ground truth.

``bringup --python-m --config <overlay>`` starts sim_robot + rt_core + driver_host + bridge with
the scenario's world merged over config/; the runner is a plain ROS user: it waits for ``odom``
and ``scan``, publishes the scenario's ``cmd_vel`` segments at 20 Hz (then zero), kills the
processes the scenario names (kill -9; bringup restarts them) when the robot has truly covered
the distance given, and samples the simulator's truth over its socket every 20 ms (pose, speed,
distance travelled, clearance, contacts, the moving obstacles' offsets, world events). The
verdict never reads odometry.
"""

from __future__ import annotations

import math
import os
import random
import shutil
import signal
import tempfile
import threading
import time
from typing import Any, Callable

import yaml

from m4k_bench.scenarios.bounds import bounds, REST_V, SAMPLE_S, stop_line
from m4k_bench.scenarios.geometry import Scene
from m4k_bench.scenarios.judge import judge, Result
from m4k_bench.scenarios.spec import Scenario
from m4k_bringup.bringup import bringup_argv
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import config

__all__ = ['Result', 'log_digest', 'run_scenario']

STARTUP_TIMEOUT_S = 60.0
SETTLE_S = 1.0            # after the last command: zero commands, then sampled until at rest
CMD_PERIOD_S = 0.05


def _bringup(argv: list[str], env: dict[str, str], log_path: str) -> Child:
    """Return the stack's bringup for one run: its own session, output to ``log_path``.

    Stopped as Ctrl-C would: SIGINT to its whole session, 20 s, then SIGKILL (5 s).
    """
    return Child('bringup', argv, env,
                 output=Output(log_path=log_path, log_append=False, log_header=False),
                 stopping=Stopping(sig=signal.SIGINT, group=True, timeout=20.0, kill_timeout=5.0))


IMU_FRESH_S = 0.2    # an IMU heading older than this is not steered on (imu_unplugged)


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class _Ros:
    """The runner's ROS side: cmd_vel out, odom/scan seen."""

    def __init__(self) -> None:
        from geometry_msgs.msg import Twist
        from nav_msgs.msg import Odometry
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import LaserScan
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, args=[])
        self.node = rclpy.create_node('m4k_scenario', context=self.ctx)
        self.twist = Twist()
        self.pub = self.node.create_publisher(Twist, 'cmd_vel', 10)
        from std_msgs.msg import Bool
        self.estop_msg = Bool()
        self.estop_pub = self.node.create_publisher(Bool, 'e_stop', 10)
        self.odom = self.scan = 0
        self.yaw: float | None = None       # the robot's own heading (odometry), for ``hold``
        self.imu_yaw: float | None = None   # the IMU's heading, preferred for ``hold``
        self.imu_at = -math.inf             # monotonic s of the last IMU message
        self.node.create_subscription(Odometry, 'odom', self._on_odom, qos_profile_sensor_data)
        from sensor_msgs.msg import Imu
        self.node.create_subscription(Imu, 'imu', self._on_imu, qos_profile_sensor_data)
        self.node.create_subscription(LaserScan, 'scan', self._on_scan, qos_profile_sensor_data)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)

    def _on_odom(self, msg: Any) -> None:
        self.odom += 1
        self.yaw = _yaw(msg.pose.pose.orientation)

    def _on_imu(self, msg: Any) -> None:
        q = msg.orientation
        self.imu_yaw = _yaw(q)
        self.imu_at = time.monotonic()

    def heading(self) -> tuple[float | None, float | None]:
        """Return (IMU yaw while fresh else None, odometry yaw)."""
        fresh = time.monotonic() - self.imu_at < IMU_FRESH_S
        return (self.imu_yaw if fresh else None), self.yaw

    def _on_scan(self, msg: Any) -> None:
        self.scan += 1

    def spin(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            self.ex.spin_once(timeout_sec=left)

    def send(self, v: float, w: float) -> None:
        self.twist.linear.x, self.twist.angular.z = float(v), float(w)
        self.pub.publish(self.twist)

    def e_stop(self, on: bool) -> None:
        self.estop_msg.data = bool(on)
        self.estop_pub.publish(self.estop_msg)

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()
        self.ctx.try_shutdown()


def _truth(runtime_dir: str) -> dict[str, Any] | None:
    from m4k_drivers.simbus import read_truth
    try:
        return read_truth(runtime_dir, timeout_s=1.0)
    except (OSError, ValueError):
        return None


def run_scenario(sc: Scenario, work_dir: str, *, short: bool = False,
                 progress: Callable[[str], None] = lambda s: None,
                 env: dict[str, str] | None = None) -> Result:
    """Run ``sc`` once (``short``: the test's version) and return the judged result.

    ``env``: the stack's environment (default this process's); the runtime directory and the
    world report are the run's own, always.
    """
    from m4k_bench.soak import children
    overlay = dict(sc.overlay, world=sc.world)
    os.makedirs(work_dir, exist_ok=True)
    overlay_path = os.path.join(work_dir, f'{sc.name}.overlay.yaml')
    with open(overlay_path, 'w', encoding='utf-8') as f:
        yaml.safe_dump(overlay, f)
    raw = config.load_layered(overlay_path, (env or os.environ).get('M4K_CONFIG_DIR'))
    cmds = sc.scaled(short)
    v = max((abs(c.v) for c in cmds), default=0.0)
    b = bounds(raw, v, sc.stop, any(c.w != 0.0 for c in cmds))
    res = Result(sc.name, sc.expected(), sc.commanded_distance(short), distance_tol=b.distance_tol,
                 stop_bound_s=b.stop_s)
    runtime_dir = tempfile.mkdtemp(prefix=f'm4k-scen-{sc.name}-')
    env = dict(env or os.environ, M4K_RUNTIME_DIR=runtime_dir,
               M4K_WORLD_REPORT=os.path.join(runtime_dir, 'world.json'))
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', env['ROS_DOMAIN_ID'])
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    log_path = os.path.join(work_dir, f'{sc.name}.bringup.log')
    proc = _bringup(bringup_argv(overlay_path), env, log_path).start()
    ros = _Ros()
    try:
        end = time.monotonic() + STARTUP_TIMEOUT_S
        while time.monotonic() < end and (ros.odom == 0 or ros.scan == 0):
            if not proc.alive():
                break
            ros.spin(0.1)
        if ros.odom == 0 or ros.scan == 0:
            res.failures.append(f'the stack did not come up (odom {ros.odom}, scan {ros.scan})')
            return res
        ros.spin(0.5)          # every sensor has reported: the guard is fresh
        if sc.e_stop:          # requested before the drive, as an operator would
            for _ in range(4):
                ros.e_stop(True)
                ros.spin(0.25)
        progress(f'{sc.name}: stack up, driving {res.commanded:.2f} m commanded')
        _drive(sc, cmds, ros, runtime_dir, proc.pid, res, children, _held_at_stop(sc, raw))
    finally:
        ros.close()
        proc.stop()
        with open(log_path, 'rb') as f:
            res.log_tail = log_digest(f.read().decode(errors='replace').splitlines())
        shutil.rmtree(runtime_dir, ignore_errors=True)
    judge(sc, res, b, raw)
    return res


# What a failed run's report quotes from the stack's log: its warnings and errors (a latched
# fault, an e-stop, a stale link, a host's drops by reason) say why it failed; the last lines,
# the shutdown, rarely do.
_NOTABLE = (' WARNING', ' ERROR', ' CRITICAL', 'fault', 'latch', 'e-stop', 'stale', 'stall')


def log_digest(lines: list[str], notable: int = 25, tail: int = 6) -> str:
    """Return the stack log lines a failure report quotes.

    The first ``notable`` warnings, errors and fault lines before the last ``tail`` lines, in
    log order, each once.
    """
    last = len(lines) - tail
    picked = [i for i, ln in enumerate(lines[:max(last, 0)])
              if any(k in ln for k in _NOTABLE)]
    out = [lines[i] for i in picked[:notable]]
    if len(picked) > notable:
        out.append(f'... ({len(picked) - notable} more such lines)')
    if picked and last > picked[-1] + 1:
        out.append('...')
    return '\n'.join(out + lines[max(last, 0):])


HOLD_GAIN = 1.0           # rad/s per rad of heading error (heading: hold)
HOLD_MAX_W = 0.3          # rad/s


def _commander(ros: _Ros, plan: list[tuple[float, float, float, bool]], done: threading.Event,
               stop: threading.Event) -> threading.Thread:
    """Publish the plan's segments at 20 Hz on their own clock (never held up by sampling).

    A ``hold`` segment steers on the robot's own heading, as a navigation stack fusing its IMU
    would: the IMU's yaw while it reports (odometry's heading drifts with the wheels' slip and
    an uncalibrated track, and edge-of-face obstacles need the path straight to the cm), else
    odometry's. The verdict stays on ground truth: w = -gain * error.
    """
    def run() -> None:
        t_seg = nxt = time.monotonic()
        for v, w, dur, hold in plan:
            targets = ros.heading()
            while not stop.is_set() and time.monotonic() - t_seg < dur:
                err = None
                for target, yaw in zip(targets, ros.heading(), strict=True):
                    if hold and target is not None and yaw is not None:
                        err = math.remainder(yaw - target, 2.0 * math.pi)
                        break
                if err is not None:
                    w = max(-HOLD_MAX_W, min(HOLD_MAX_W, -HOLD_GAIN * err))
                ros.send(v, w)
                nxt += CMD_PERIOD_S
                stop.wait(max(0.0, nxt - time.monotonic()))
            t_seg += dur
        done.set()
        while not stop.is_set():          # zero until the runner has seen the robot at rest
            ros.send(0.0, 0.0)
            stop.wait(CMD_PERIOD_S)
    th = threading.Thread(target=run, name='scenario-cmd_vel', daemon=True)
    th.start()
    return th


HELD_S = 2.5          # a guard stop held this long in front of its obstacle ends the drive


def _held_at_stop(sc: Scenario, raw: dict[str, Any]) -> Callable[[list[dict[str, Any]]], bool]:
    """Return a test of whether a guard-stop scenario's robot rests at its obstacle.

    True once the robot has moved, rests (the simulator's ``rest_since_ns``) for ``HELD_S``
    and the judge's exact front clearance is within the guard's stop zone at rest plus its
    release margin (and 0.1 m): the stop the scenario is about happened, so the rest of the
    command time would only show the robot standing there. Other scenarios run their time.
    """
    if sc.stop not in ('sonar', 'laser'):
        return lambda s: False
    from m4k_rt.control.params import control_params
    g = control_params(raw.get('control')).guard
    scene = Scene(raw, lateral=g.lateral_margin)
    near = stop_line(raw, 0.0) + g.release_margin + 0.1

    def held(s: list[dict[str, Any]]) -> bool:
        x = s[-1]
        rest = x.get('rest_since_ns')
        if rest is None or float(x['travelled']) < 0.05 or \
                int(x['t_ns']) - int(rest) < HELD_S * 1e9:
            return False
        return scene.front_clearance(float(x['x']), float(x['y']), float(x['theta']),
                                     x.get('obstacle_offsets') or []) < near
    return held


def _drive(sc: Scenario, cmds: Any, ros: _Ros, runtime_dir: str, bringup_pid: int, res: Result,
           children: Callable[[int], dict[str, int]],
           held: Callable[[list[dict[str, Any]]], bool] = lambda s: False) -> None:
    plan = [(c.v, c.w, c.t, c.hold) for c in cmds] + [(0.0, 0.0, SETTLE_S, False)]
    faults = list(sc.faults)
    done, stop = threading.Event(), threading.Event()
    th = _commander(ros, plan, done, stop)
    try:
        nxt = t_drive = time.monotonic()
        while not done.is_set():
            t = _truth(runtime_dir)
            if t is not None:
                res.samples.append(t)
                res.cmd_end_ns = int(t['t_ns'])
                for f in list(faults):
                    due = (time.monotonic() - t_drive >= f.after) if f.after is not None \
                        else t['travelled'] >= f.travelled
                    if due:
                        pid = children(bringup_pid).get(f.kill)
                        if pid:
                            t_kill = time.monotonic_ns()
                            os.kill(pid, signal.SIGKILL)
                            res.samples[-1] = dict(t, killed=f.kill, kill_ns=t_kill)
                            faults.remove(f)
                if held(res.samples):
                    break
            nxt += SAMPLE_S
            ros.spin(max(0.0, nxt - time.monotonic()))
        # at rest? keep sampling (zero commands) up to a few more seconds until it is
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            t = _truth(runtime_dir)
            if t is not None:
                res.samples.append(t)
                if abs(t['v']) < REST_V and abs(t['w']) < 0.02:
                    break
            ros.spin(SAMPLE_S)
    finally:
        stop.set()
        th.join(5.0)
    for f in faults:
        when = f'{f.after} s' if f.after is not None else f'{f.travelled} m'
        res.failures.append(f'fault kill {f.kill} at {when} never happened')
