"""The plain-ROS baseline: the actuator control run the classical way (paper Fig. 10, "ROS").

The same control code as the RT actuator task (:class:`m4k_rt.control.BaseController`) and
the same motor handler as the driver host (backend from ``devices.yaml``: by default the
``sim_robot``'s motors over the sim-bus), but run inside an rclpy node: a 10 ms timer whose
callback reads the encoders, steps the controller and writes the DAC codes by calling the
handler directly, in a normal
(SCHED_OTHER) process with the garbage collector on -- what a ROS driver node does.
``cmd_vel`` comes in through a subscription in the same executor, ``odom`` goes out every
``odom_every_n``-th cycle.

Every callback is timed exactly like an RT task cycle (design.md, "Timing"): ``t_rel`` the
ideal release ``t0 + k * period`` of the steady-clock timer, ``t_start`` when the callback
runs, ``t_end`` after the DAC write, ``expirations`` the releases that passed since the
previous callback (rcl timers skip missed periods, like the RT loop). Samples go into a
preallocated buffer and are written as CSV at exit (the same columns as the recorder's
``samples.csv``), so the bench analyses both with the same code.

The baseline has no sonar or laser, so the collision guard is not applied here (the RT
actuator applies it from the sensor tasks' readings; its cost is a few float compares).
"""

from __future__ import annotations

import argparse
from array import array
import csv
import math
import os
import sys
import time
from typing import Any, Sequence

__all__ = ['BaselineNode', 'TimingBuffer', 'build_motor', 'main']

TASK_NAME = 'baseline'


class TimingBuffer:
    """Preallocated (t_rel, t_start, t_end, expirations) rows; drops and counts when full."""

    __slots__ = ('capacity', 't_rel', 't_start', 't_end', 'expirations', 'count', 'dropped')

    def __init__(self, capacity: int) -> None:
        """Preallocate ``capacity`` rows."""
        if not isinstance(capacity, int) or isinstance(capacity, bool) or capacity < 1:
            raise ValueError(f'timing buffer capacity must be an int >= 1, got {capacity!r}')
        self.capacity = capacity
        self.t_rel = array('q', bytes(8 * capacity))
        self.t_start = array('q', bytes(8 * capacity))
        self.t_end = array('q', bytes(8 * capacity))
        self.expirations = array('q', bytes(8 * capacity))
        self.count = 0
        self.dropped = 0

    def record(self, t_rel: int, t_start: int, t_end: int, expirations: int) -> None:
        """Store one callback's timing (O(1), no allocation)."""
        i = self.count
        if i >= self.capacity:
            self.dropped += 1
            return
        self.t_rel[i] = t_rel
        self.t_start[i] = t_start
        self.t_end[i] = t_end
        self.expirations[i] = expirations
        self.count = i + 1

    def write_csv(self, path: str, task: str = TASK_NAME) -> int:
        """Write the rows as ``task,t_rel_ns,t_start_ns,t_end_ns,expirations``; return rows."""
        directory = os.path.dirname(path)
        try:
            if directory:
                os.makedirs(directory, exist_ok=True)
            with open(path, 'w', newline='', encoding='utf-8') as f:
                w = csv.writer(f)
                w.writerow(['task', 't_rel_ns', 't_start_ns', 't_end_ns', 'expirations'])
                for i in range(self.count):
                    w.writerow([task, self.t_rel[i], self.t_start[i], self.t_end[i],
                                self.expirations[i]])
        except OSError as exc:
            raise OSError(exc.errno, f'baseline: cannot write timing CSV {path!r}: '
                          f'{exc.strerror} (errno {exc.errno})') from exc
        return self.count


def release_index(t_start_ns: int, t0_ns: int, period_ns: int, last_k: int) -> int:
    """Return the index k of the release a callback at ``t_start_ns`` serves (> ``last_k``).

    The release served is the latest one at or before ``t_start``; a callback that runs
    early (clock granularity) still counts as the next release, never the previous one.
    """
    k = (t_start_ns - t0_ns) // period_ns
    return k if k > last_k else last_k + 1


def build_motor(raw: dict[str, Any]) -> Any:
    """Build the motor handler from the layered config (``devices.motor``).

    A ``sim`` motor is the sim_robot's, reached through the sim-bus socket in the runtime
    directory ($M4K_RUNTIME_DIR): start ``sim_robot`` first, as bringup and the bench do.
    """
    from m4k_drivers import config as dconfig
    from m4k_drivers import registry
    section = ((raw.get('devices') or {}).get('motor')) or {'backend': 'sim'}
    valid = dconfig.validate_device('motor', section, 'devices.motor')
    ctx = registry.BuildContext(
        world_config=raw.get('world') or {},
        runtime_dir=(raw.get('runtime') or {}).get('runtime_dir') or None)
    return registry.create('motor', valid, ctx)


def _make_node_class() -> type:
    # rclpy is imported lazily so the pure parts of this module (TimingBuffer,
    # release_index) import without ROS.
    from geometry_msgs.msg import Twist, TwistStamped
    from nav_msgs.msg import Odometry as OdometryMsg
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.clock import Clock, ClockType
    from rclpy.node import Node

    from m4k_drivers.handler import Status
    from m4k_drivers.motors import WheelCommand
    from m4k_rt.control import BaseController

    class _BaselineNode(Node):
        """rclpy node: a 10 ms timer runs the actuator control calling the motor handler."""

        def __init__(self, params: Any, motor: Any, timing: TimingBuffer) -> None:
            super().__init__('m4k_baseline')
            period_ms = self.declare_parameter(
                'period_ms', 10.0, ParameterDescriptor(
                    description='control period in ms (the RT actuator task uses 10 ms)',
                    read_only=True)).value
            stamped = self.declare_parameter(
                'cmd_vel_stamped', False, ParameterDescriptor(
                    description='true: cmd_vel is TwistStamped, false: Twist',
                    read_only=True)).value
            self.frame_id = self.declare_parameter(
                'odom_frame', 'odom', ParameterDescriptor(description='odom frame id')).value
            if not (isinstance(period_ms, float) and 0.1 <= period_ms <= 1000.0):
                raise ValueError(f'period_ms must be in 0.1..1000 ms, got {period_ms!r}')
            self.period_ns = int(round(period_ms * 1e6))
            self.ctl = BaseController(params, self.period_ns * 1e-9)
            self.motor = motor
            self.timing = timing
            self.odom_every = params.odom_every_n
            self._odom_countdown = self.odom_every
            self._wheel = WheelCommand
            self._ok = Status.OK
            self.read_errors = 0
            self.write_errors = 0
            self.rejected = 0
            self.last_k = -1
            self.odom_pub = self.create_publisher(OdometryMsg, 'odom', 10)
            self._odom = OdometryMsg()
            self._odom.header.frame_id = self.frame_id
            self._odom.child_frame_id = 'base_link'
            msg_type = TwistStamped if stamped else Twist
            self._stamped = bool(stamped)
            self.create_subscription(msg_type, 'cmd_vel', self._on_cmd, 10)
            steady = Clock(clock_type=ClockType.STEADY_TIME)
            self.timer = self.create_timer(self.period_ns * 1e-9, self._on_timer, clock=steady)
            # rcl's steady clock is CLOCK_MONOTONIC: the first release is one period from now.
            self.t0_ns = time.monotonic_ns() + self.timer.time_until_next_call()

        def _on_cmd(self, msg: Any) -> None:
            twist = msg.twist if self._stamped else msg
            v, w = twist.linear.x, twist.angular.z
            if not (math.isfinite(v) and math.isfinite(w)):
                self.rejected += 1
                self.get_logger().warning('cmd_vel with NaN/inf rejected',
                                          throttle_duration_sec=1.0)
                return
            self.ctl.command(v, w, time.monotonic_ns())

        def _on_timer(self) -> None:
            t_start = time.monotonic_ns()
            k = release_index(t_start, self.t0_ns, self.period_ns, self.last_k)
            expirations = k - self.last_k
            self.last_k = k
            ctl = self.ctl
            reading = self.motor.read()
            if reading.status == self._ok:
                enc = reading.value
                ctl.encoders(enc.left_angle, enc.right_angle, enc.t_ns, t_start, enc.status)
            else:
                self.read_errors += 1
            ctl.step(t_start)
            if self.motor.write(self._wheel(ctl.left_code, ctl.right_code, ctl.enable)) \
                    != self._ok:
                self.write_errors += 1
            self._odom_countdown -= 1
            if self._odom_countdown <= 0:
                self._odom_countdown = self.odom_every
                self._publish_odom()
            t_end = time.monotonic_ns()
            self.timing.record(self.t0_ns + k * self.period_ns, t_start, t_end, expirations)

        def _publish_odom(self) -> None:
            o = self.ctl.odom
            m = self._odom
            m.header.stamp = self.get_clock().now().to_msg()
            m.pose.pose.position.x = o.x
            m.pose.pose.position.y = o.y
            m.pose.pose.orientation.z = math.sin(o.yaw * 0.5)
            m.pose.pose.orientation.w = math.cos(o.yaw * 0.5)
            m.twist.twist.linear.x = o.v
            m.twist.twist.angular.z = o.w
            self.odom_pub.publish(m)

    return _BaselineNode


def BaselineNode(params: Any, motor: Any, timing: TimingBuffer) -> Any:  # noqa: N802
    """Create the baseline node (rclpy must be initialised)."""
    return _make_node_class()(params, motor, timing)


def _parse_args(argv: Sequence[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog='baseline', description='Plain-ROS baseline: the actuator control in an rclpy '
        'timer calling the motor handler directly (paper Fig. 10).')
    ap.add_argument('--duration', type=float, default=0.0,
                    help='stop after this many seconds (0: run until Ctrl-C / SIGTERM)')
    ap.add_argument('--timing-csv', default='',
                    help='write per-callback timing here at exit (default: none)')
    ap.add_argument('--capacity', type=int, default=0,
                    help='timing rows to preallocate (default: duration / period + 1000, '
                    'or 360000 when running without --duration)')
    ap.add_argument('--config', default=None, help='config overlay YAML (as rt_core --config)')
    args = ap.parse_args(list(argv))
    if not (args.duration >= 0.0 and math.isfinite(args.duration)):
        ap.error(f'--duration must be >= 0 s, got {args.duration!r}')
    if args.capacity < 0:
        ap.error(f'--capacity must be >= 0, got {args.capacity!r}')
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the baseline node; write the timing CSV at exit."""
    from m4k_rt.stopsignals import StopSignals
    stop = StopSignals().install()  # first: a stop during start-up ends it cleanly, too
    try:
        return _main(argv, stop)
    finally:
        stop.restore()
        if stop.stopping:
            sys.stderr.write(f'baseline: stopped ({stop.name}); motors safe\n')


def _main(argv: Sequence[str] | None, stop: Any) -> int:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.task import Future
    from rclpy.utilities import remove_ros_args

    from m4k_bridge.shutdown import spin_until_shutdown, stop_aware_start
    from m4k_rt import config as rtconfig
    from m4k_rt.control import control_params

    args_all = sys.argv if argv is None else ['baseline', *argv]
    args = _parse_args(remove_ros_args(args_all)[1:])
    raw = rtconfig.load_layered(args.config)
    params = control_params(raw.get('control'))
    capacity = args.capacity or (int(args.duration * 100) + 1000 if args.duration else 360_000)
    timing = TimingBuffer(capacity)
    if stop.stopping:
        return 0
    motor = build_motor(raw)
    motor.configure()
    motor.activate()
    # rclpy's handlers (SIGINT and SIGTERM: the bench stops us with SIGTERM) shut the context
    # down, which ends the spin, and chain to ours.
    rclpy.init(args=args_all)
    node = None
    try:
        if not stop.stopping:
            node = stop_aware_start(lambda: BaselineNode(params, motor, timing), stop)
        if node is not None and not stop.stopping:
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            # A future nobody completes: spin until the duration is up (or forever).
            spin_until_shutdown(lambda: executor.spin_until_future_complete(
                Future(), timeout_sec=args.duration or None), node.context)
    except KeyboardInterrupt:  # before the node spins
        pass
    finally:
        motor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if args.timing_csv:
        n = timing.write_csv(args.timing_csv)
        sys.stderr.write(f'baseline: {n} callbacks timed ({timing.dropped} dropped) -> '
                         f'{args.timing_csv}\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
