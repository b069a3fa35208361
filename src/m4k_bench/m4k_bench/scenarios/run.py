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

from dataclasses import dataclass, field
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

from m4k_bench.scenarios.bounds import (
    Bounds,
    bounds,
    REST_V,
    SAMPLE_S,
    SCHED_S,
    STAY_M,
    stop_line,
    STOP_MARGIN_M,
)
from m4k_bench.scenarios.geometry import Scene
from m4k_bench.scenarios.spec import Scenario
from m4k_bringup.bringup import bringup_argv
from m4k_bringup.child import Child, Output, Stopping
from m4k_rt import config

__all__ = ['Result', 'run_scenario']

STARTUP_TIMEOUT_S = 60.0
SETTLE_S = 1.0            # after the last command: zero commands, then sampled until at rest
CMD_PERIOD_S = 0.05


@dataclass
class Result:
    """What one run measured and the verdict."""

    name: str
    expected: str
    commanded: float
    travelled: float = math.nan
    min_clearance: float = math.nan
    contacts: int = -1
    stop_s: float | None = None
    stop_bound_s: float | None = None
    stop_m: float | None = None         # m travelled from the trigger to rest
    stop_bound_m: float | None = None   # the allowed stopping distance (guard stops)
    peak_decel: float = math.nan        # m/s^2, ground truth
    max_decel: float = math.nan         # m/s^2, mu * g of the world's robot
    distance_tol: float = math.nan
    failures: list[str] = field(default_factory=list)
    samples: list[dict[str, Any]] = field(default_factory=list)
    log_tail: str = ''
    cmd_end_ns: int | None = None       # truth time the scripted commands ended
    peak_speed: float = math.nan        # m/s, body or wheel rim, ground truth

    @property
    def passed(self) -> bool:
        """Return True when every check held."""
        return not self.failures


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
    b = bounds(raw, v, sc.stop)
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
            res.log_tail = b'\n'.join(f.read().splitlines()[-15:]).decode(errors='replace')
        shutil.rmtree(runtime_dir, ignore_errors=True)
    _judge(sc, res, b, raw)
    return res


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


def _judge(sc: Scenario, res: Result, b: Bounds, raw: dict[str, Any]) -> None:
    s = res.samples
    if not s:
        res.failures.append('no ground truth sampled')
        return
    from m4k_rt.control.params import control_params
    # the front band the guard watches: the face and the guard's lateral margin each side
    scene = Scene(raw, lateral=control_params(raw.get('control')).guard.lateral_margin)
    for x in s:                       # the judge's own geometry, on every ground-truth sample
        x['clearance'], x['front_clearance'] = scene.judge_sample(x)
    last = s[-1]
    res.travelled = float(last['travelled'])
    # the judge's exact clearance per sample, and the simulator's own 5 ms minimum
    res.min_clearance = min(min(x['clearance'] for x in s), min(_m(x['min_clearance']) for x in s))
    res.contacts = int(last['contacts'])
    touching = sum(1 for x in s if x['clearance'] <= 0.0)
    if res.contacts:
        res.failures.append(f'{res.contacts} contact(s)')
    elif touching:
        res.failures.append(f'contact: the footprint touches a surface in {touching} sample(s)')
    if not res.min_clearance > 0.0:
        res.failures.append(f'minimum clearance {res.min_clearance:.3f} m')
    res.peak_decel = _peak_decel(s)
    res.max_decel = b.max_decel
    if res.peak_decel > b.max_decel:
        res.failures.append(f'peak deceleration {res.peak_decel:.2f} m/s^2 on ground truth > '
                            f'{b.max_decel:.2f} m/s^2 (mu * g): physically impossible braking')
    if sc.distance and abs(res.travelled - res.commanded) > b.distance_tol:
        res.failures.append(f'travelled {res.travelled:.3f} m, commanded {res.commanded:.3f} m '
                            f'(tolerance {b.distance_tol:.3f} m)')
    if sc.distance_m is not None and abs(res.travelled - sc.distance_m) > b.distance_tol:
        res.failures.append(f'travelled {res.travelled:.3f} m, expected {sc.distance_m:.3f} m '
                            f'(tolerance {b.distance_tol:.3f} m)')
    radius = scene.robot.wheel_radius_m
    res.peak_speed = max(max(abs(float(x['v'])),
                             abs(float(x.get('wheel_speed_left', 0.0))) * radius,
                             abs(float(x.get('wheel_speed_right', 0.0))) * radius) for x in s)
    if sc.max_speed is not None and not res.peak_speed < sc.max_speed:
        res.failures.append(f'peak speed {res.peak_speed:.3f} m/s on ground truth (body or wheel '
                            f'rim) >= {sc.max_speed:g} m/s')
    if sc.motor_fault:
        _judge_motor_fault(res, s)
    elif all(c.v >= 0.0 for c in sc.commands):
        back = _backed_up(s)
        if back > STAY_M:
            res.failures.append(f'backed up {back:.3f} m on ground truth with no reverse '
                                f'command: a motion nobody commanded')
    if sc.still_after_estop:
        _judge_estop_release(res, s)
    if sc.max_w_after_kill is not None:
        hit = next((i for i, x in enumerate(s) if x.get('killed')), None)
        if hit is None:
            res.failures.append('the kill never happened')
        else:
            w_max = max(abs(float(x['w'])) for x in s[hit:])
            if not w_max < sc.max_w_after_kill:
                res.failures.append(f'|w| up to {w_max:.3f} rad/s after the kill of '
                                    f'{s[hit]["killed"]} >= {sc.max_w_after_kill:g}')
    if sc.stop:
        _judge_stop(sc, res, b, raw, s)


def _backed_up(s: list[dict[str, Any]]) -> float:
    """Return how far the body moved backwards along its own heading (m, ground truth)."""
    back = 0.0
    for a, c in zip(s, s[1:], strict=False):
        th = float(a['theta'])
        step = ((float(c['x']) - float(a['x'])) * math.cos(th) +
                (float(c['y']) - float(a['y'])) * math.sin(th))
        if step < 0.0:
            back -= step
    return back


FAULT_HOLD_S = 1.0   # a latched fault: outputs zero and at rest this long before the commands end


def _judge_motor_fault(res: Result, s: list[dict[str, Any]]) -> None:
    """Judge a latched motor fault on ground truth: the commands drive on, the robot does not.

    Over the last ``FAULT_HOLD_S`` of the scripted commands both armatures get 0 V or the
    amplifiers are disabled, and the robot is at rest -- although the command source never
    stopped asking for motion.
    """
    end = res.cmd_end_ns
    if end is None:
        res.failures.append('motor fault: no samples while commanded')
        return
    # the commands reached the wheels before the latch (a stack that never drove is no test)
    if not any(abs(float(u)) > 0.5 for x in s for u in x.get('motor_volts') or []):
        res.failures.append('motor fault: the motors were never driven (no armature voltage '
                            'above 0.5 V on ground truth): nothing was supervised')
        return
    tail = [x for x in s if end - FAULT_HOLD_S * 1e9 <= int(x['t_ns']) <= end]
    if len(tail) < 3:
        res.failures.append('motor fault: too few samples at the end of the commands')
        return
    driven = [x for x in tail if x.get('motor_enabled', True) and
              any(abs(float(u)) > 1e-6 for u in x.get('motor_volts') or [])]
    moving = [x for x in tail if abs(float(x['v'])) >= REST_V or abs(float(x['w'])) >= 0.02]
    if driven or moving:
        res.failures.append(f'motor fault not latched: in the last {FAULT_HOLD_S:g} s of the '
                            f'commands {len(driven)} sample(s) drive the motors, {len(moving)} '
                            f'move')


def _judge_estop_release(res: Result, s: list[dict[str, Any]]) -> None:
    """Judge the e-stop release: no motion once the contact closes (no reset, command live).

    The contact (``estop_open`` on ground truth) must have opened while the robot was being
    driven, then closed; from the closing sample on, the robot stays at rest.
    """
    i_open = next((i for i, x in enumerate(s) if x.get('estop_open')), None)
    if i_open is None:
        res.failures.append('e-stop: the contact never opened during the drive')
        return
    if float(s[i_open]['travelled']) < 0.02:
        res.failures.append('e-stop: the contact opened before the robot moved (the stack came '
                            'up late): the release under a live command was not exercised')
        return
    i_close = next((i for i in range(i_open, len(s)) if not s[i].get('estop_open')), None)
    if i_close is None:
        res.failures.append('e-stop: the contact never closed again during the drive')
        return
    end = res.cmd_end_ns
    if end is not None and int(s[i_close]['t_ns']) > end:
        res.failures.append('e-stop: the contact closed after the commands ended: the release '
                            'under a live command was not exercised')
        return
    # the robot may still be coasting when the contact closes: from its rest on
    i_rest = next((i for i in range(i_close, len(s)) if abs(float(s[i]['v'])) < REST_V), None)
    if i_rest is None:
        res.failures.append('e-stop: never at rest after the release')
        return
    after = s[i_rest:]
    moved = float(after[-1]['travelled']) - float(after[0]['travelled'])
    v_max = max(abs(float(x['v'])) for x in after)
    w_max = max(abs(float(x['w'])) for x in after)
    held = (int(after[-1]['t_ns']) - int(s[i_close]['t_ns'])) / 1e9
    if moved > STAY_M or v_max >= REST_V or w_max >= 0.02:
        res.failures.append(f'e-stop release restarted motion: {moved:.3f} m, up to '
                            f'{v_max:.3f} m/s, {w_max:.3f} rad/s with no reset')
    elif held < 1.0:
        res.failures.append(f'e-stop: only {held:.2f} s observed after the release')


def _judge_stop(sc: Scenario, res: Result, b: Bounds, raw: dict[str, Any],
                s: list[dict[str, Any]]) -> None:
    trig = _trigger(sc, s, raw, b.t_react)
    if trig is None:
        res.failures.append(f'stop ({sc.stop}): its trigger never happened')
        return
    t0, travelled0, _ = trig       # its speed: the guard judge uses each sample's own
    # The simulator stamps when the robot came to rest (1 ms steps): the first sample
    # after the trigger that reports rest says since when, whatever the sampling jitter.
    i_rest = next((i for i, x in enumerate(s)
                   if x['t_ns'] >= t0 and x.get('rest_since_ns') is not None), None)
    if i_rest is None:
        res.failures.append(f'stop ({sc.stop}): never at rest after the trigger')
        return
    rest = s[i_rest]
    res.stop_s = max(int(rest['rest_since_ns']) - t0, 0) / 1e9
    res.stop_m = max(float(rest['travelled']) - travelled0, 0.0)
    if b.t_react is not None:
        _judge_guard_stop(sc, res, b, raw, s, i_rest)
    if b.stop_s is not None and res.stop_s > b.stop_s:
        res.failures.append(f'stop took {res.stop_s:.3f} s > bound {b.stop_s:.3f} s')
    if b.stays_stopped:
        after = s[i_rest:]
        moved = float(after[-1]['travelled']) - float(rest['travelled'])
        v_max = max(abs(float(x['v'])) for x in after)
        held_s = (int(after[-1]['t_ns']) - int(rest['t_ns'])) / 1e9
        if moved > STAY_M or v_max >= REST_V:
            res.failures.append(f'stop ({sc.stop}): moved again after the stop ({moved:.3f} m, '
                                f'up to {v_max:.3f} m/s)')
        elif held_s < 1.0:
            res.failures.append(f'stop ({sc.stop}): at rest only {held_s:.2f} s before the run '
                                f'ended: staying stopped not shown')


INTRUSION_M = 0.01   # m the gap may close beyond the robot's travel in one sample (noise)


def _deepest(s: list[dict[str, Any]], raw: dict[str, Any], b: Bounds,
             i_rest: int) -> tuple[float, float, float, str] | None:
    """Return ``(measure m, v m/s, allowed m, kind)`` of the worst passage past the stop line.

    The depth of a ground-truth sample is how far the exact front clearance is inside the stop
    line at the true speed of that moment. A passage is a run of samples inside the line. One
    the robot drove into: its measure is its deepest depth, allowed ``v (t_react + SCHED_S) +
    STOP_MARGIN_M`` at that sample's speed (kind ``'reach'``). One entered by the gap closing
    more than ``INTRUSION_M`` beyond the robot's own travel since the previous sample is an
    *intrusion* -- an obstacle that stepped in inside the line (a person at 1 m/s) or walks
    towards the robot; the guard sizes its line by its own speed only, so it is
    held to the straight-approach stopping distance from that moment: its measure is the travel
    to rest, allowed :meth:`Bounds.stop_distance` (kind ``'intrusion'``).
    None when the robot never got past the line.
    """
    worst: tuple[float, float, float, str] | None = None

    def keep(c: tuple[float, float, float, str]) -> None:
        nonlocal worst
        if worst is None or c[0] - c[2] > worst[0] - worst[2]:
            worst = c

    entry: tuple[float, float, bool] | None = None     # (travelled, v, intrusion)
    prev: dict[str, Any] | None = None
    for x in s[:i_rest + 1]:
        v = abs(float(x['v']))
        depth = stop_line(raw, v) - float(x['front_clearance'])
        if entry is not None and entry[2]:
            continue           # an intrusion is held from its moment to rest (below)
        if depth <= 0.0:
            entry, prev = None, x
            continue
        if entry is None:
            # the gap closed by more than the robot drove since the last sample: the
            # obstacle moved in (stepped into the band, or walks towards the robot)
            moved_in = prev is not None and (
                float(prev['front_clearance']) - float(x['front_clearance']) >
                float(x['travelled']) - float(prev['travelled']) + INTRUSION_M)
            entry = (float(x['travelled']), v, moved_in)
        prev = x
        if not entry[2]:
            keep((depth, v, b.reach(v), 'reach'))
    if entry is not None and entry[2]:
        keep((float(s[i_rest]['travelled']) - entry[0], entry[1],
              b.stop_distance(entry[1]) or 0.0, 'intrusion'))
    return worst


def _judge_guard_stop(sc: Scenario, res: Result, b: Bounds, raw: dict[str, Any],
                      s: list[dict[str, Any]], i_rest: int) -> None:
    """Judge a guard stop (sonar / laser) on ground truth: two obligations.

    1. **In time.** The robot never gets further past the stop line at its true speed ``v``
       of the moment than its sensors' reaction lets it: ``v (t_react + SCHED_S) +
       STOP_MARGIN_M`` (:meth:`Bounds.reach`); where an obstacle stepped in past the line, it
       stops within the straight-approach stopping distance from then (:func:`_deepest`).
       Once the guard sees the line crossed it brakes, the speed falls and the line with it
       faster than the gap closes. The speed is the
       instantaneous one: with the slow-down zone the robot comes in on a falling speed riding
       the line, and a line sized by an earlier, higher speed would hold that approach to a
       stopping distance it never had to keep.
    2. **The promise.** Among static obstacles, it comes to rest no nearer than the guard's
       ``stop_distance`` less ``STOP_MARGIN_M``: d(v) is sized so that it does, at every speed.
    """
    from m4k_rt.control.params import control_params
    worst = _deepest(s, raw, b, i_rest)
    if worst is not None:
        measure, v_at, allowed, kind = worst
        res.stop_m, res.stop_bound_m = measure, allowed
        if measure > allowed and kind == 'reach':
            res.failures.append(f'went {measure:.3f} m past the stop line at {v_at:.2f} m/s > '
                                f'{allowed:.3f} m (v (t_react + sched) + margin: t_react '
                                f'{b.t_react:.3f} s, sched {SCHED_S:.3f} s)')
        elif measure > allowed:
            res.failures.append(f'an obstacle stepped in past the stop line at {v_at:.2f} m/s '
                                f'and the robot went {measure:.3f} m on > {allowed:.3f} m '
                                f'(v (t_react + sched) + v^2 / 2a + margin: t_react '
                                f'{b.t_react:.3f} s, a {b.a_brake:.2f} m/s^2)')
    else:
        res.stop_m, res.stop_bound_m = 0.0, b.reach(res.peak_speed)
    if any(o.get('path') for o in (sc.world.get('obstacles') or []) if isinstance(o, dict)):
        return        # a person walking on: the gap can close after the stop
    promise = control_params(raw.get('control')).guard.stop_distance
    at_rest = float(s[i_rest]['front_clearance'])
    if at_rest < promise - STOP_MARGIN_M:
        res.failures.append(f'came to rest {at_rest:.3f} m from the obstacle ahead: inside the '
                            f"guard's stop_distance {promise:.3f} m (less the judge's "
                            f'{STOP_MARGIN_M:.3f} m margin)')


def _m(v: float | None) -> float:
    """Return a truth clearance in m (null: nothing there, inf)."""
    return math.inf if v is None else float(v)


def _peak_decel(s: list[dict[str, Any]]) -> float:
    """Return the peak braking deceleration (m/s^2, >= 0) on ground truth.

    The simulator's own peak since the previous sample when it reports one, else the
    difference of the true speed between consecutive samples.
    """
    peaks = [float(x['peak_decel']) for x in s if x.get('peak_decel') is not None]
    if peaks:
        return max(0.0, max(peaks))
    best = 0.0
    for a, c in zip(s, s[1:], strict=False):
        dt = (int(c['t_ns']) - int(a['t_ns'])) / 1e9
        if dt <= 0:
            continue
        va, vc = float(a['v']), float(c['v'])
        if abs(vc) < abs(va) and va * vc >= 0:     # slowing down, not reversing
            best = max(best, (abs(va) - abs(vc)) / dt)
    return best


def _trigger(sc: Scenario, s: list[dict[str, Any]], raw: dict[str, Any],
             t_react: float | None = None) -> tuple[int, float, float] | None:
    """Return (ns, travelled m, v m/s) when the robot had to start stopping (ground truth).

    Guard stops: the sample where the judge's exact front clearance first falls below the
    guard's stop line, interpolated (linear in travelled) back to the crossing between that
    sample and the one before. The line is sized by the highest true speed over the preceding
    reaction time (``t_react``, the cause's), not the instantaneous one: once a guard brakes,
    its speed -- and with it the instantaneous d(v) -- shrinks faster than the gap, so a guard
    that tripped a few mm early (its sensors read a little short, it sizes d(v) by the larger
    of commanded and measured speed) would never "cross" an instantaneous line at all. The
    obligation is: within d(v) of the obstacle at the speed it was driving, the robot must be
    braking; a guard acting late still crosses the line at full speed and is held to it.
    """
    if sc.stop in ('sonar', 'laser'):
        prev = None
        window_ns = int(max(t_react or 0.0, SAMPLE_S) * 1e9)
        recent: list[tuple[int, float]] = []
        for x in s:
            v = abs(float(x['v']))
            t_x = int(x['t_ns'])
            recent.append((t_x, v))
            while recent and recent[0][0] < t_x - window_ns:
                recent.pop(0)
            v = max(u for _, u in recent)
            line = stop_line(raw, v)
            fc = x['front_clearance']
            if fc < line:
                if prev is None or not prev['front_clearance'] > fc:
                    return int(x['t_ns']), float(x['travelled']), v
                k = (prev['front_clearance'] - line) / (prev['front_clearance'] - fc)
                k = min(max(k, 0.0), 1.0)
                t = int(prev['t_ns'] + k * (int(x['t_ns']) - int(prev['t_ns'])))
                tr = float(prev['travelled']) + k * (float(x['travelled']) -
                                                      float(prev['travelled']))
                vv = max(abs(float(prev['v'])), v)
                return t, tr, vv
            prev = x
        return None
    if sc.stop in ('sonar_unplugged', 'laser_unplugged'):
        want = 'sonar' if sc.stop == 'sonar_unplugged' else 'lrf'
        for x in s:
            for e in x.get('events', []):
                if e['unplug'] == want:
                    return int(e['t_ns']), float(x['travelled']), abs(float(x['v']))
        return None
    want = 'bridge' if sc.stop == 'bridge_killed' else 'driver_host'
    hit = next((x for x in s if x.get('killed') == want), None)
    return None if hit is None else (int(hit['kill_ns']), float(hit['travelled']),
                                     abs(float(hit['v'])))
