"""The m4k local planner node (``m4k_planner``): DWA over ``scan`` + ``odom`` -> ``cmd_vel``.

The ROS 2 adapter of :mod:`m4k_bench.planning.dwa` -- the stand-in for the paper's navigation
stack (``base_local_planner``), producing a centre velocity command every 50 ms. It subscribes
``odom`` (nav_msgs/Odometry) and ``scan`` (sensor_msgs/LaserScan), turns each scan into odom
points using the odometry pose at the scan's stamp and the laser's mounting pose
(``laser_mount``: tf2_msgs is not on PyPI, so no tf listener), and publishes ``cmd_vel``
(Twist, or TwistStamped with ``use_stamped_vel``) at ``rate_hz`` plus the planner state on
``planner_state`` (std_msgs/String: ``idle``, ``moving``, ``recovering``, ``blocked``,
``goal_reached``, ``waiting_odom``, ``waiting_scan``).

The measured velocity handed to the planner is the rate of change of the odometry pose
between messages (the twist's 10 ms encoder quotient spikes); the twist is used for the first
message only. Fail-safe: no odometry within ``odom_timeout`` or no scan within
``scan_timeout`` -> zero command. The goal (odom frame) comes from ``goal_x`` / ``goal_y``
(NaN: none) and may be changed at run time with ``ros2 param set``. Every parameter is declared
once, by its schema Field (:mod:`m4k_bench.planning.params`; every ``dwa.*`` one is a
:class:`m4k_bench.planning.dwa.DwaConfig` field): descriptors and validation come from it, and
a bad value stops the node with exit code 2 and a message naming it.
Run: ``python -m m4k_bench.planning.node --ros-args -p goal_x:=3.0``.
"""

from __future__ import annotations

from collections import deque
import math
import sys
import time
from typing import Any, Sequence

from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import SetParametersResult
import rclpy
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String

from m4k_bench.planning.dwa import DWA, DwaConfig, DwaError, DwaPlanner, State
from m4k_bench.planning.params import ParamError, problem, SPECS
from m4k_bench.planning.scan import PointMemory, scan_to_points, ScanError
from m4k_bridge.descriptors import descriptor
from m4k_rt.stopsignals import StopSignals

__all__ = ['NODE_NAME', 'ParamError', 'PlannerNode', 'main']

NODE_NAME = 'm4k_planner'
_ODOM_HISTORY = 200          # odometry poses kept to look up the pose at a scan's stamp
_MIN_RATE_DT_NS = 20_000_000  # odometry messages closer than this are not differentiated

def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class PlannerNode(Node):
    """DWA local planner: ``odom`` + ``scan`` in, ``cmd_vel`` out at a fixed rate."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare parameters, build the planner, subscribe and start the timer.

        Raise :class:`ParamError` naming a bad parameter.
        """
        super().__init__(NODE_NAME, **kwargs)
        d = self._declare
        self.rate_hz = d('rate_hz')
        goal_x, goal_y = d('goal_x'), d('goal_y')
        self.mount = tuple(d('laser_mount'))
        self.use_stamped = d('use_stamped_vel')
        self.odom_timeout = d('odom_timeout')
        self.scan_timeout = d('scan_timeout')
        memory_s = d('memory_s')
        self.base_frame = d('base_frame')
        dwa = {name: d(f'dwa.{name}') for name in DWA}
        try:
            self.planner = DwaPlanner(DwaConfig(**dwa))
        except DwaError as exc:
            raise ParamError(f'dwa.{exc}') from None
        self.memory = PointMemory(memory_s)
        if math.isfinite(goal_x) and math.isfinite(goal_y):
            self.planner.set_goal(goal_x, goal_y)
        elif not (math.isnan(goal_x) and math.isnan(goal_y)):
            raise ParamError(f'goal_x/goal_y: both finite or both NaN, got {(goal_x, goal_y)!r}')
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._odom: deque[tuple[int, float, float, float]] = deque(maxlen=_ODOM_HISTORY)
        self._vel = (0.0, 0.0)
        self._odom_mono = -math.inf
        self._scan_mono = -math.inf
        self._state = ''
        self.plans = 0
        self.scans = 0
        self.errors = 0
        self.create_subscription(Odometry, 'odom', self._on_odom,
                                 QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(LaserScan, 'scan', self._on_scan, qos_profile_sensor_data)
        self._cmd_pub = self.create_publisher(TwistStamped if self.use_stamped else Twist,
                                              'cmd_vel', 10)
        self._state_pub = self.create_publisher(String, 'planner_state', 10)
        self.create_timer(1.0 / self.rate_hz, self._tick)
        self.get_logger().info(
            f'DWA planner at {self.rate_hz:g} Hz, max_v {self.planner.cfg.max_v:g} m/s, goal '
            f'{self.planner.goal}, laser mount {self.mount}')

    def _declare(self, name: str) -> Any:
        """Declare parameter ``name`` from its Field; return its value, judged by the Field."""
        f = SPECS[name]
        try:
            value = self.declare_parameter(name, f.default, descriptor(f)).value
        except (InvalidParameterTypeException, InvalidParameterValueException,
                ParameterException) as exc:
            raise ParamError(name, str(exc)) from None
        if f.type == 'float' and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if f.type == 'float[]' and not isinstance(value, str):
            value = list(value)
        reason = problem(name, value)
        if reason is not None:
            raise ParamError(name, reason)
        return value

    def _on_set_parameters(self, params: Sequence[Parameter]) -> SetParametersResult:
        goal = dict(zip(('goal_x', 'goal_y'), self.planner.goal or (math.nan, math.nan),
                        strict=True))
        for p in params:
            if p.name in goal:
                goal[p.name] = float(p.value)
            elif p.name != 'use_sim_time':
                return SetParametersResult(successful=False,
                                           reason=f'{p.name}: not changeable at run time')
        if math.isfinite(goal['goal_x']) and math.isfinite(goal['goal_y']):
            self.planner.set_goal(goal['goal_x'], goal['goal_y'])
            self.get_logger().info(f'new goal {self.planner.goal}')
        elif math.isnan(goal['goal_x']) and math.isnan(goal['goal_y']):
            self.planner.clear_goal()
        return SetParametersResult(successful=True)

    # -- inputs ------------------------------------------------------------------------------
    def _on_odom(self, msg: Odometry) -> None:
        p = msg.pose.pose
        x, y, yaw = p.position.x, p.position.y, _yaw(p.orientation)
        v, w = msg.twist.twist.linear.x, msg.twist.twist.angular.z
        if not all(math.isfinite(a) for a in (x, y, yaw, v, w)):
            self.errors += 1
            self.get_logger().warn('odom with non-finite values dropped',
                                   throttle_duration_sec=5.0)
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if self._odom and stamp - self._odom[-1][0] >= _MIN_RATE_DT_NS:
            # The twist is the RT odometry's 10 ms encoder difference quotient, which spikes
            # when one encoder sample is late (seen: 2 m/s at a 0.25 m/s cruise); the pose
            # change over the ~50 ms between messages is the same odometry, much steadier.
            t0, x0, y0, th0 = self._odom[-1]
            dt = (stamp - t0) * 1e-9
            dth = math.atan2(math.sin(yaw - th0), math.cos(yaw - th0))
            mid = th0 + 0.5 * dth
            v = ((x - x0) * math.cos(mid) + (y - y0) * math.sin(mid)) / dt
            w = dth / dt
        elif self._odom:
            v, w = self._vel            # a repeated stamp: nothing new to differentiate
        self._odom.append((stamp, x, y, yaw))
        self._vel = (v, w)
        self._odom_mono = time.monotonic()

    def _pose_at(self, stamp_ns: int) -> tuple[float, float, float]:
        """Return the odometry pose at ``stamp_ns``, interpolated, clamped to the history."""
        hist = self._odom
        if stamp_ns <= hist[0][0]:
            return hist[0][1:]
        for i in range(len(hist) - 1, 0, -1):
            t1 = hist[i][0]
            t0 = hist[i - 1][0]
            if t0 <= stamp_ns <= t1:
                a = (stamp_ns - t0) / (t1 - t0) if t1 > t0 else 1.0
                _, x0, y0, th0 = hist[i - 1]
                _, x1, y1, th1 = hist[i]
                dth = math.atan2(math.sin(th1 - th0), math.cos(th1 - th0))
                return (x0 + a * (x1 - x0), y0 + a * (y1 - y0), th0 + a * dth)
        return hist[-1][1:]

    def _on_scan(self, msg: LaserScan) -> None:
        if not self._odom:
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        try:
            pts = scan_to_points(msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min,
                                 msg.range_max, self.mount, self._pose_at(stamp))
        except ScanError as exc:
            self.errors += 1
            self.get_logger().warn(f'scan dropped: {exc}', throttle_duration_sec=5.0)
            return
        self.memory.add(time.monotonic(), pts)
        self.scans += 1
        self._scan_mono = time.monotonic()

    # -- the 20 Hz loop ----------------------------------------------------------------------
    def _tick(self) -> None:
        now = time.monotonic()
        v = w = 0.0
        if now - self._odom_mono > self.odom_timeout:
            state = 'waiting_odom'
        elif now - self._scan_mono > self.scan_timeout:
            state = 'waiting_scan'
        else:
            stamp, x, y, yaw = self._odom[-1]
            # How old the odometry is now (bridge, DDS and this executor in between).
            age = (self.get_clock().now().nanoseconds - stamp) * 1e-9
            try:
                plan = self.planner.plan(now, (x, y, yaw), self._vel, self.memory.points(now),
                                         age=age)
            except DwaError as exc:
                self.errors += 1
                self.get_logger().warn(f'planning failed, stopping: {exc}',
                                       throttle_duration_sec=5.0)
                state = 'error'
            else:
                v, w, state = plan.v, plan.w, plan.state.value
                self.plans += 1
                if plan.state is State.GOAL_REACHED and self._state != state:
                    self.get_logger().info(f'goal reached: {plan.goal_distance:.3f} m from it')
        self._publish(v, w)
        if state != self._state:
            self.get_logger().info(f'state: {state}')
            self._state = state
        self._state_pub.publish(String(data=state))

    def _publish(self, v: float, w: float) -> None:
        twist = Twist()
        twist.linear.x = float(v)
        twist.angular.z = float(w)
        if self.use_stamped:
            msg = TwistStamped()
            msg.header.stamp = self.get_clock().now().to_msg()
            msg.header.frame_id = self.base_frame
            msg.twist = twist
            self._cmd_pub.publish(msg)
        else:
            self._cmd_pub.publish(twist)

    def stop(self) -> None:
        """Publish one zero command (on shutdown)."""
        self._publish(0.0, 0.0)


def main(args: Sequence[str] | None = None) -> int:
    """Run the planner node; exit code 2 on a bad parameter, naming it."""
    # Our own stop handling (not rclpy's) keeps the context alive long enough to send the zero
    # command; rclpy's handler would shut it down first. Installed first, so a stop during
    # start-up ends it cleanly, too.
    stop = StopSignals().install()
    rclpy.init(args=list(sys.argv if args is None else args),
               signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        try:
            node = PlannerNode()
        except ParamError as exc:
            sys.stderr.write(f'{NODE_NAME}: {exc}\n')
            return 2
        while not stop.stopping:
            rclpy.spin_once(node, timeout_sec=0.1)
    except ExternalShutdownException:
        pass
    finally:
        if node is not None:
            if rclpy.ok():
                node.stop()
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    if stop.stopping:
        sys.stderr.write(f'{NODE_NAME}: stopped ({stop.name})\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
