"""The m4k ROS 2 bridge node (``m4k_bridge``): the only place of the stack that speaks ROS.

It never runs control logic. Inbound, ``cmd_vel`` (Twist, or TwistStamped with
``enable_stamped_cmd_vel``; a publisher of the other type is reported) is checked (NaN/inf
rejected, limits clamped, both counted) and forwarded
as VELOCITY_CMD on the ``cmd`` port; ``led`` (ColorRGBA) becomes an LED override on ``led_in``.
The bridge does not repeat commands: when cmd_vel stops, the RT actuator brakes after its own
``control.cmd_vel_timeout``; the bridge's ``cmd_vel_timeout`` only labels the input idle in
diagnostics. On shutdown it sends one zero command. ``e_stop`` (std_msgs/Bool) and the
``~/reset_odometry`` service (std_srvs/Trigger) go to the RT actuator on the same ``cmd`` port
(:mod:`m4k_bridge.safety`: the latch itself lives in the RT process).

Outbound, datagrams from the RT process become ``odom``, ``imu``, ``scan``, ``sonar``,
``cmd_vel_out`` (the velocity the RT actuator applies), ``e_stop_state``, ``motor_fault``
(:mod:`m4k_bridge.faults`; reset by ``~/reset_motor_fault``), and
through :mod:`m4k_bridge.tf` ``joint_states``, ``tf``, ``tf_static`` and
``robot_description``; the monitor's TASK_STATS / RT_STATUS become ``rt_status`` and, with
the link, command and device health (:mod:`m4k_bridge.health`), ``diagnostics``. Port I/O
runs in one thread per port (:mod:`m4k_bridge.ports` explains why); the executor thread
does all ROS work.

The RT process may restart at any time: each port re-links by itself, the outage is logged
once when it starts and once when it ends, with the gap, and counted in diagnostics
(:class:`m4k_bridge.health.BridgeHealth` keeps that state; this module only logs it).
"""

from __future__ import annotations

import collections
import sys
import time
from typing import Any, Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import (
    SetParametersResult,
)
import rclpy
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterException,
)
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, LaserScan, Range
from std_msgs.msg import ColorRGBA, Header
import yaml

from m4k_bridge import convert, params
from m4k_bridge.descriptors import descriptor
from m4k_bridge.diagnostics import make_status, RtMonitor
from m4k_bridge.faults import MotorFaultInterface, SafetyReport
from m4k_bridge.faulttrace import TraceWriter
from m4k_bridge.flightrec_ros import FlightRecorder
from m4k_bridge.health import BridgeHealth, Status
from m4k_bridge.ports import PortPump
from m4k_bridge.safety import SafetyInterface
from m4k_bridge.shutdown import spin_until_shutdown, stop_aware_start
from m4k_bridge.tf import RobotStatePublisher
from m4k_msgs.msg import RtStatus
from m4k_rt import channel, config, description, estop_request, protocol, yamlload
from m4k_rt.schema import Field
from m4k_rt.stopsignals import StopSignals

__all__ = ['BridgeNode', 'late_command_s', 'main', 'param_files']

_RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# cmd_vel is taken best effort: a reliable reader makes a reliable writer (Nav2, teleop) keep
# and re-send the samples it could not deliver, so after a network outage the robot would get
# a burst of commands from before the outage and drive on them. A velocity stream needs the
# newest sample or none; the RT actuator brakes when none comes (control.cmd_vel_timeout).
_CMD_VEL_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
_INBOX_MAX = 4096
_WATCH_PERIOD_S = 0.25
_GRAPH_EVERY = 4          # watch ticks between looks at the cmd_vel publishers (1 s)
_TWIST = 'geometry_msgs/msg/Twist'
_TWIST_STAMPED = 'geometry_msgs/msg/TwistStamped'
_descriptor = descriptor


def _diagnostic(s: Status) -> Any:
    return make_status(s.name, s.level, s.message, s.values, hardware_id=s.hardware_id)


def late_command_s(received_ns: int, now_ns: int, timeout_s: float) -> float | None:
    """Return how long a command waited since it arrived, when longer than ``timeout_s``.

    None: in time, or not judged (no reception time from the middleware: 0; the timeout
    off: 0). Both times are this machine's system clock.
    """
    if received_ns <= 0 or timeout_s <= 0:
        return None
    waited = (now_ns - received_ns) * 1e-9
    return waited if waited > timeout_s else None


class BridgeNode(Node):
    """ROS 2 <-> XDDP bridge of the m4k RT process."""

    def __init__(self, **kwargs: Any) -> None:
        """Declare and check parameters, open the ports, create publishers and timers.

        Raise :class:`m4k_bridge.params.ParamError` naming a bad parameter.
        """
        super().__init__(params.NODE_NAME, **kwargs)
        self._ready = False
        self.p = self._declare()
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        p = self.p
        self._seq = 0
        self._led_seq = 0
        self._monitor = RtMonitor(p['stats_window'], p['rt_stale_timeout'])
        self._inbox: collections.deque[tuple[str, bytes, int]] = collections.deque()
        runtime_dir = p['runtime_dir'] or None
        self._runtime_dir = runtime_dir or channel.default_runtime_dir()
        group = p['runtime_group'] or None
        try:     # as the RT side checks it, before anything links in it
            channel.check_runtime_dir(self._runtime_dir, group)
        except OSError as exc:
            raise params.ParamError('runtime_dir', str(exc)) from None
        # Outages, counters and the link / cmd_vel / device statuses (m4k_bridge.health).
        self.health = BridgeHealth(time.monotonic_ns(), self._runtime_dir)

        qos_sensor = qos_profile_sensor_data
        self._odom_pub = self.create_publisher(Odometry, p.topic('odom'), _RELIABLE)
        self._imu_pub = self.create_publisher(Imu, p.topic('imu'), qos_sensor)
        self._scan_pub = self.create_publisher(LaserScan, p.topic('scan'), qos_sensor)
        self._sonar_pub = self.create_publisher(Range, p.topic('sonar'), qos_sensor)
        self._diag_pub = self.create_publisher(DiagnosticArray, p.topic('diagnostics'),
                                               _RELIABLE)
        self._applied_pub = self.create_publisher(TwistStamped, p.topic('cmd_vel_out'),
                                                  _RELIABLE)
        self._rt_pub = self.create_publisher(RtStatus, p.topic('rt_status'), _RELIABLE)
        self._robot_state = self._setup_robot_state()
        self._init_safety()
        if p['use_stamped_vel']:
            self.get_logger().warning('use_stamped_vel is deprecated: set enable_stamped_cmd_vel '
                                      '(the name Nav2 and TurtleBot3 use)')
        self._cmd_vel_sub = self._subscribe_cmd_vel(p.stamped_cmd_vel)
        self._cmd_vel_topic = self._cmd_vel_sub.topic_name   # resolved (namespace, remaps)
        self._cmd_vel_auto = p.auto_cmd_vel      # decided by the first publisher, then fixed
        self._mismatch_logged: set[str] = set()
        self._watch_ticks = 0
        self.create_subscription(ColorRGBA, p.topic('led'), self._on_led, 10)

        # The flight recorder (docs/recording.md): a bounded ring of this node's topics, dumped
        # as a bag by a thread of its own on an e-stop, guard stop, fault or deadline miss.
        # It has no subscription to the bridge's inputs: their callbacks hand it what arrives.
        self._flight = FlightRecorder(self, p, self._cmd_vel_type)
        # a latched fault's supervision trace, written beside the flight recorder's dumps
        self._fault_trace = TraceWriter(self._flight.directory, self.get_logger().warning)
        self._safety.record = self._flight.keep_e_stop
        self._handlers = self._datagram_handlers()
        self._wake = self.create_guard_condition(self._unless_shut_down(self._drain_inbox))
        # The cmd port's first datagram on every link is the e-stop, when one is requested.
        safety = self._safety
        self._pumps = {role: PortPump(role, p.port(role), self._deliver, runtime_dir,
                                      p['relink_interval'], group=group,
                                      preamble=(safety.link_preamble if role == 'cmd'
                                                else None))
                       for role in params.PORT_ROLES}
        self._diag_timer = self.create_timer(p['diagnostics_period'],
                                             self._unless_shut_down(self._publish_diagnostics))
        self._rt_timer = self.create_timer(p['rt_status_period'],
                                           self._unless_shut_down(self._publish_rt_status))
        self.create_timer(_WATCH_PERIOD_S, self._watch)
        for pump in self._pumps.values():
            pump.start()
        self._closed = False
        self._ready = True
        self.get_logger().info('waiting for the RT process in {} (ports {})'.format(
            self._runtime_dir, ', '.join(str(p.port(r)) for r in params.PORT_ROLES)))

    def _unless_shut_down(self, fn: Callable[[], None]) -> Callable[[], None]:
        """Wrap a callback: once SIGINT/SIGTERM shut the context down, publishing fails.

        The signal may land while a callback runs; its RCLError ('context is invalid') is
        then the expected end of the node, not a crash.
        """
        def call() -> None:
            if not self.context.ok():
                return
            try:
                fn()
            except Exception:
                if self.context.ok():
                    raise

        return call

    # --- parameters ---------------------------------------------------------------------------

    def _declare(self) -> params.BridgeParams:
        """Declare every parameter; derived ones default to the layered configuration's values.

        Bringup and the launch file pass the derived values; started by hand (``ros2 run``)
        the node computes them itself from the layered configuration, so both get the same.
        """
        values = {}

        def declare(s: Field, default: Any) -> None:
            try:
                self.declare_parameter(s.name, default, _descriptor(s))
            except InvalidParameterTypeException as exc:
                raise params.ParamError(s.name, str(exc)) from None
            except (InvalidParameterValueException, ParameterException) as exc:
                raise params.ParamError(s.name, str(exc)) from None
            values[s.name] = self.get_parameter(s.name).value

        for s in params.SPECS:
            if s.name not in params.DERIVED:
                declare(s, s.default)
        try:
            doc = config.load_layered()
        except config.ConfigError as exc:
            raise params.ParamError('<config>', 'cannot load the layered configuration the '
                                    'derived parameters come from: {}'.format(exc)) from None
        self._derived = params.derived_values(doc, values['base_frame'],
                                              values['footprint_frame'])
        for s in params.SPECS:
            if s.name in params.DERIVED:
                declare(s, self._derived.get(s.name, s.default))
        return params.from_values({k: list(v) if not isinstance(v, (str, bool, float, int))
                                   else v for k, v in values.items()})

    def _on_set_parameters(self, changes: list[Parameter]) -> SetParametersResult:
        for prm in changes:
            value = prm.value
            if not isinstance(value, (str, bool, float, int)) and value is not None:
                value = list(value)
            reason = params.validate(prm.name, value)
            if reason is not None:
                return SetParametersResult(successful=False,
                                           reason='{}: {}'.format(prm.name, reason))
        if self._ready:
            merged = dict(self.p.values)
            merged.update((prm.name, prm.value if isinstance(prm.value, (str, bool, float))
                           else list(prm.value)) for prm in changes)
            try:
                params.from_values(merged)
            except params.ParamError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, changes: list[Parameter]) -> None:
        if not self._ready:
            return
        merged = dict(self.p.values)
        merged.update((prm.name, prm.value if isinstance(prm.value, (str, bool, float))
                       else list(prm.value)) for prm in changes)
        old = self.p
        self.p = params.from_values(merged)
        self._monitor.set_window(self.p['stats_window'])
        self._monitor.stale_ns = int(self.p['rt_stale_timeout'] * 1e9)
        self._safety.reset_timeout = self.p['reset_odometry_timeout']
        self._safety.e_stop_timeout = self.p['e_stop_timeout']
        # odom and tf read the frames from here: a run-time change reaches both.
        self._robot_state.set_frames(self.p['odom_frame'], self.p.odom_child)
        if self.p['diagnostics_period'] != old['diagnostics_period']:
            self._diag_timer.cancel()
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self.create_timer(
                self.p['diagnostics_period'], self._unless_shut_down(self._publish_diagnostics))
        if self.p['rt_status_period'] != old['rt_status_period']:
            self._rt_timer.cancel()
            self.destroy_timer(self._rt_timer)
            self._rt_timer = self.create_timer(
                self.p['rt_status_period'], self._unless_shut_down(self._publish_rt_status))

    # --- inbound: ROS -> RT ---------------------------------------------------------------------

    def _on_twist(self, msg: Twist, info: Any) -> None:
        self._flight.keep_cmd_vel(msg)      # as received, before any check
        if self._waited_too_long(info):
            return
        self._command(msg.linear.x, msg.angular.z)

    def _on_twist_stamped(self, msg: TwistStamped, info: Any) -> None:
        self._flight.keep_cmd_vel(msg)
        if self._waited_too_long(info):
            return
        stamp = msg.header.stamp
        if not self._safety.gate.accept(stamp.sec * 1_000_000_000 + stamp.nanosec):
            self.get_logger().warning(
                'cmd_vel stamped before the last e_stop release: dropped ({} so far)'.format(
                    self._safety.gate.rejected), throttle_duration_sec=1.0)
            return
        self._command(msg.twist.linear.x, msg.twist.angular.z)

    def _waited_too_long(self, info: Any) -> bool:
        """Drop (and count) a cmd_vel that waited in this node longer than cmd_vel_timeout.

        ``info`` is rclpy's MessageInfo: its ``received_timestamp`` is when the middleware
        took the sample in on this machine (system clock, never the sender's). A starved bridge
        can run its callbacks seconds after the commands arrived -- after a link drop, for
        commands from before it -- and by then the RT actuator has braked on their absence;
        forwarding one would restart the robot on a command its sender has long replaced.
        """
        rx_ns = int((info or {}).get('received_timestamp', 0) or 0)
        late_s = late_command_s(rx_ns, time.time_ns(), self.p['cmd_vel_timeout'])
        if late_s is None:
            return False
        n = self.health.on_cmd_problem('cmd_vel_late', time.monotonic_ns())
        self.get_logger().warning(
            'cmd_vel processed {:.2f} s after it arrived (> cmd_vel_timeout {} s: a stall?): '
            'dropped ({} so far)'.format(late_s, self.p['cmd_vel_timeout'], n),
            throttle_duration_sec=1.0)
        return True

    def _command(self, linear_x: float, angular_z: float) -> None:
        if self._safety.gating:
            # An e-stop is requested: nothing to forward, whatever the RT latch says (a
            # restarted RT process may not have latched yet).
            self._safety.gated += 1
            self.get_logger().warning(
                'cmd_vel while the e-stop is requested: not forwarded ({} so far; release with '
                'e_stop false)'.format(self._safety.gated), throttle_duration_sec=5.0)
            return
        try:
            v, w, clamped = convert.velocity_command(
                linear_x, angular_z, self.p['max_linear_velocity'],
                self.p['max_angular_velocity'])
        except convert.NonFiniteCommand as exc:
            n = self.health.on_cmd_problem('cmd_vel_rejected_nonfinite', time.monotonic_ns())
            self.get_logger().warning('{}: rejected ({} so far)'.format(exc, n),
                                      throttle_duration_sec=1.0)
            return
        if clamped:
            n = self.health.on_cmd_problem('cmd_vel_clamped', time.monotonic_ns())
            self.get_logger().warning(
                'cmd_vel ({:.3f}, {:.3f}) beyond the limits ({}, {}): clamped ({} so far)'.format(
                    linear_x, angular_z, self.p['max_linear_velocity'],
                    self.p['max_angular_velocity'], n),
                throttle_duration_sec=1.0)
        self._send_velocity(v, w)
        self.health.on_cmd_vel_forwarded(time.monotonic_ns())

    def _send_velocity(self, v: float, w: float) -> None:
        self._pumps['cmd'].send(self._velocity_datagram(v, w))

    def _velocity_datagram(self, v: float, w: float) -> bytes:
        data = protocol.encode(protocol.Kind.VELOCITY_CMD, self._seq, time.monotonic_ns(), v, w)
        self._seq = protocol.next_seq(self._seq)
        return data

    def _on_led(self, msg: ColorRGBA) -> None:
        try:
            fields = convert.led_command(msg.r, msg.g, msg.b, msg.a)
        except convert.NonFiniteCommand as exc:
            self.health.count('led_rejected_nonfinite')
            self.get_logger().warning('{}: rejected'.format(exc), throttle_duration_sec=1.0)
            return
        data = protocol.encode(protocol.Kind.LED, self._led_seq, time.monotonic_ns(), *fields)
        self._led_seq = protocol.next_seq(self._led_seq)
        self._pumps['led_in'].send(data)
        self.health.count('led_forwarded')

    # --- outbound: RT -> ROS --------------------------------------------------------------------

    def _deliver(self, role: str, data: bytes, rx_ns: int) -> None:
        """Queue a datagram from a pump thread and wake the executor (thread-safe)."""
        if len(self._inbox) >= _INBOX_MAX:
            self.health.count('inbox_overflow')
            return
        self._inbox.append((role, data, rx_ns))
        try:
            self._wake.trigger()
        except Exception:  # noqa: BLE001 -- node being destroyed: the datagram is moot
            pass

    def _drain_inbox(self) -> None:
        now_mono = time.monotonic_ns()
        now_ros = self.get_clock().now().nanoseconds
        while self._inbox:
            role, data, rx_ns = self._inbox.popleft()
            self._handle(role, data, rx_ns, now_mono, now_ros)

    def _handle(self, role: str, data: bytes, rx_ns: int, now_mono: int, now_ros: int) -> None:
        try:
            header, payload = protocol.decode(data)
        except protocol.ProtocolError as exc:
            self.health.count('malformed_' + role)
            self.get_logger().warning('malformed datagram on port {!r}: {}'.format(role, exc),
                                      throttle_duration_sec=5.0)
            return
        self._flight.on_datagram(header.kind, payload)
        if header.kind in (protocol.Kind.TASK_HEALTH, protocol.Kind.FORBIDDEN_SITE):
            self._monitor.feed(header.kind, payload, rx_ns)
            return
        self.health.on_seq(role, header.seq)
        stamp = convert.ros_stamp_ns(header.stamp_ns, now_mono, now_ros)
        handler = self._handlers.get(header.kind)
        if handler is not None:
            taken = handler(payload, stamp, rx_ns)
        else:    # the monitor's own kinds (TASK_STATS, RT_STATUS, PORT_STATS, ...)
            taken = self._monitor.feed(header.kind, payload, rx_ns, header.stamp_ns)
        if not taken:
            self.health.count('unexpected_' + role)

    # --- one handler per datagram kind: it returns False for a datagram nobody expected ----

    def _datagram_handlers(self) -> dict[int, Callable[[Any, int, int], bool]]:
        """Return the handler of each datagram kind the RT side sends the bridge."""
        K = protocol.Kind
        return {K.ODOMETRY: self._on_odometry, K.SAFETY_STATUS: self._on_safety_status,
                K.FAULT_RESET: self._on_fault_reset, K.APPLIED_VELOCITY: self._on_applied,
                K.SET_POSE: self._on_set_pose_ack, K.IMU: self._on_imu,
                K.LASER_SCAN: self._on_scan, K.SONAR: self._on_sonar,
                K.LED: self._on_led_shown, K.ODOM_RESET: self._on_odom_reset_ack,
                K.FAULT_TRACE: self._fault_trace.on_row}

    def _on_odometry(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        p = self.p
        self.health.on_odometry(payload, rx_ns)
        self._odom_pub.publish(convert.odometry_msg(
            payload, stamp, p.frame(p['odom_frame']), p.frame(p.odom_child),
            p['odom_pose_covariance_diagonal'], p['odom_twist_covariance_diagonal']))
        self._robot_state.on_odometry(payload, stamp)
        self._safety.on_latch(bool(payload.flags & protocol.ODOM_E_STOP), rx_ns)
        self._safety.on_flags(payload.flags)
        self._faults.on_flags(payload.flags, rx_ns)
        return True

    def _on_safety_status(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        line = self._safety_report.feed(payload, rx_ns)
        if line is not None:
            if payload.flags & protocol.SAFETY_TEST_WEAKENED:
                self.get_logger().error(line)
            else:
                self.get_logger().info(line)
        return True

    def _on_fault_reset(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        return bool(self._faults.on_reset_ack(payload))

    def _on_applied(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        p = self.p
        out = TwistStamped(header=Header(stamp=convert.time_msg(stamp),
                                         frame_id=p.frame(p.odom_child)))
        out.twist.linear.x, out.twist.angular.z = payload.linear_x, payload.angular_z
        self._applied_pub.publish(out)
        return True

    def _on_set_pose_ack(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        return bool(self._safety.on_set_pose_ack(payload))

    def _on_imu(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        p = self.p
        msg = convert.imu_msg(payload, stamp, p.frame(p['imu_frame']),
                              p['imu_orientation_covariance_diagonal'],
                              p['imu_angular_velocity_covariance_diagonal'],
                              p['imu_linear_acceleration_covariance_diagonal'])
        if msg is None:
            self.health.count('imu_not_ready')
        else:
            self._imu_pub.publish(msg)
        return True

    def _on_scan(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        p = self.p
        self._scan_pub.publish(convert.scan_msg(payload, stamp, p.frame(p['laser_frame'])))
        return True

    def _on_sonar(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        p = self.p
        self.health.on_sonar(payload.status)
        sonar = convert.sonar_msg(
            payload, stamp, p.frame(p['sonar_frame']), p['sonar_field_of_view'],
            p['sonar_min_range'], p['sonar_max_range'], p['sonar_no_echo'])
        if sonar is None:      # never NaN on sonar: a fault is dropped and counted
            self.health.count('sonar_dropped')
        else:
            self._sonar_pub.publish(sonar)
        return True

    def _on_led_shown(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        self.health.on_led_shown(payload)
        return True

    def _on_odom_reset_ack(self, payload: Any, stamp: int, rx_ns: int) -> bool:
        return bool(self._safety.on_reset_ack(payload.request_id))

    # --- robot state: description, joint_states, tf (m4k_bridge.tf) -----------------------

    def _setup_robot_state(self) -> RobotStatePublisher:
        """Publish the robot description and create the tf / joint_states publishers.

        Raise ParamError when ``robot_description`` (or, when it is empty, the configuration it
        is generated from) is unusable.
        """
        p = self.p
        urdf = p['robot_description'] or self._derived.get('robot_description', '')
        try:
            state = RobotStatePublisher(self, urdf, p['odom_frame'], p.odom_child,
                                        p['publish_tf'], p['publish_robot_state'],
                                        p.topic('joint_states'), p.topic('robot_description'),
                                        p['frame_prefix'], p['tf_namespaced'])
        except description.DescriptionError as exc:
            raise params.ParamError('robot_description', str(exc)) from None
        missing = [p[f] for f in ('base_frame', 'laser_frame', 'imu_frame', 'sonar_frame')
                   if p[f] not in state.links]
        if p['footprint_frame'] and p['footprint_frame'] not in state.links:
            missing.append(p['footprint_frame'])
        if missing:
            self.get_logger().warning(
                'frames {} are not links of robot_description: their messages do not connect '
                'to {!r} in tf'.format(missing, p['odom_frame']))
        return state

    # --- e-stop and odometry reset (m4k_bridge.safety) ---------------------------------

    def _init_safety(self) -> None:
        # Created before the pumps: it only needs the send path, which exists at first use.
        self._safety: SafetyInterface = SafetyInterface(
            self, lambda data: self._pumps['cmd'].send(data), self.p.topic('e_stop'),
            self.p['reset_odometry_timeout'], self.p.topic('e_stop_state'),
            self.p['e_stop_timeout'], estop_request.state_dir(runtime_dir=self._runtime_dir))
        self._faults = MotorFaultInterface(
            self, lambda data: self._pumps['cmd'].send(data), self.p.topic('motor_fault'),
            self.p['reset_odometry_timeout'])
        self._safety_report = SafetyReport()

    # --- health (m4k_bridge.health) -------------------------------------------------------

    def _watch(self) -> None:
        """Log RT process outages once per transition (BridgeHealth.watch), and port failures."""
        log = self.get_logger()
        for event in self.health.watch(time.monotonic_ns(), self._pumps,
                                       self.p['rt_stale_timeout']):
            # One call site per severity: rclpy's logger refuses a call site whose severity
            # changes between calls ('Logger severity cannot be changed between calls').
            if event.kind == 'outage_start':
                self._safety_report.lost()   # the next RT process states its caps again
            if event.severity == 'error':
                log.error(event.message)
            elif event.severity == 'warning':
                log.warning(event.message)
            else:
                log.info(event.message)
        self._safety.on_cmd_links(self._pumps['cmd'].links)
        self._watch_ticks += 1
        if self._cmd_vel_auto:
            self._decide_cmd_vel_type()
        if self._watch_ticks % _GRAPH_EVERY == 0:
            self._check_cmd_vel_types()

    def _subscribe_cmd_vel(self, stamped: bool) -> Any:
        """Subscribe cmd_vel as TwistStamped or Twist; remember which."""
        self._cmd_vel_type = _TWIST_STAMPED if stamped else _TWIST
        # Two-argument callbacks: rclpy passes each message's MessageInfo (its stubs type only
        # the one-argument form).
        callback: Any = self._on_twist_stamped if stamped else self._on_twist
        return self.create_subscription(TwistStamped if stamped else Twist,
                                        self.p.topic('cmd_vel'), callback, _CMD_VEL_QOS)

    def _decide_cmd_vel_type(self) -> None:
        """enable_stamped_cmd_vel auto: take the type of the first cmd_vel publisher, once."""
        try:
            types = {i.topic_type for i in self.get_publishers_info_by_topic(self._cmd_vel_topic)}
        except Exception:  # noqa: BLE001 -- graph unavailable while shutting down
            return
        types &= {_TWIST, _TWIST_STAMPED}
        if not types:
            return
        self._cmd_vel_auto = False
        chosen = self._cmd_vel_type if self._cmd_vel_type in types else types.pop()
        if chosen != self._cmd_vel_type:
            # The one cmd_vel subscription of this node (the flight recorder is fed from its
            # callbacks): gone before the other type is subscribed, as one participant cannot
            # hold a topic with two types.
            self.destroy_subscription(self._cmd_vel_sub)
            self._cmd_vel_sub = self._subscribe_cmd_vel(chosen == _TWIST_STAMPED)
            self._flight.set_cmd_vel_type(self._cmd_vel_type)
        self.get_logger().info('enable_stamped_cmd_vel auto: the first cmd_vel publisher on {} '
                               'uses {}: subscribed with that type'.format(self._cmd_vel_topic,
                                                                           chosen))

    def _check_cmd_vel_types(self) -> None:
        """Report publishers of the other cmd_vel type: they never match, and DDS is silent.

        A WARN in the cmd_vel diagnostic while one is on the graph, and one log line per
        foreign type naming both types.
        """
        try:
            infos = self.get_publishers_info_by_topic(self._cmd_vel_topic)
        except Exception:  # noqa: BLE001 -- graph unavailable while shutting down
            return
        foreign = sorted({i.topic_type for i in infos if i.topic_type != self._cmd_vel_type})
        text = ''
        if foreign:
            text = '{} published on {}, {} subscribed (enable_stamped_cmd_vel: {})'.format(
                ', '.join(foreign), self._cmd_vel_topic, self._cmd_vel_type,
                str(self.p['enable_stamped_cmd_vel']).lower())
            for t in foreign:
                if t not in self._mismatch_logged:
                    self._mismatch_logged.add(t)
                    self.get_logger().warning(
                        'cmd_vel type mismatch: a publisher of {} on {}, but the bridge '
                        'subscribes {}: its commands never arrive (set enable_stamped_cmd_vel '
                        'to {})'.format(t, self._cmd_vel_topic, self._cmd_vel_type,
                                        'true' if t == _TWIST_STAMPED else 'false'))
        self.health.cmd_vel_type_mismatch = text

    def _publish_rt_status(self) -> None:
        now = time.monotonic_ns()
        h = self.health
        msg = self._monitor.rt_status_msg(now, h.link_age_s(now, self._pumps),
                                          guard_fallback=h.guard_fallback(now))
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.ports = self._monitor.port_msgs(now)   # the RT side's counters (PORT_STATS)
        latch = self._safety.latch(h.last_odom, h.last_odom_ns, now)
        msg.e_stop_active, msg.e_stop_hold = latch if latch is not None else (False, False)
        odom = h.last_odom
        fresh = odom is not None and now - h.last_odom_ns <= 1_000_000_000
        self._safety_report.fill(msg, now, odom.flags if odom is not None and fresh else None)
        self._rt_pub.publish(msg)

    def _publish_diagnostics(self) -> None:
        now = time.monotonic_ns()
        h = self.health
        ports = self._pumps
        statuses = h.device_statuses(
            now, ports, {role: self.p['ports.' + role] for role in ports},
            self._monitor.device_levels(now))
        statuses.append(h.link_status(now, ports))
        statuses.append(h.cmd_status(now, self.p['cmd_vel_timeout'],
                                     ports['cmd'].dropped_unlinked, self.p['stats_window']))
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = self._monitor.task_statuses(now)
        arr.status.extend(self._monitor.host_drop_statuses(now))
        arr.status.extend(_diagnostic(s) for s in statuses)
        arr.status.append(self._safety.status(h.last_odom, h.last_odom_ns, now))
        arr.status.append(self._safety_report.status(now))
        self._diag_pub.publish(arr)

    # --- shutdown -------------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the port threads; the last datagram on ``cmd`` is a zero velocity."""
        if getattr(self, '_closed', True):
            return
        self._closed = True
        for role, pump in self._pumps.items():
            pump.close(final=self._velocity_datagram(0.0, 0.0) if role == 'cmd' else None)
        self._flight.close()

    def destroy_node(self) -> None:
        """Close the ports, then destroy the node."""
        self.close()
        super().destroy_node()


def param_files(argv: Sequence[str]) -> list[str]:
    """Return the ``--params-file`` arguments of a ROS command line, in order."""
    out = []
    args = list(argv)
    for i, a in enumerate(args[:-1]):
        if a == '--params-file':
            out.append(args[i + 1])
    return out


def _check_param_files(argv: Sequence[str]) -> None:
    for path in param_files(argv):
        try:
            with open(path, encoding='utf-8') as f:
                doc = yamlload.load(f)
        except OSError as exc:
            raise params.ParamError('--params-file', 'cannot read {!r}: {} [errno {}]'.format(
                path, exc.strerror, exc.errno)) from None
        except yamlload.DuplicateKeyError as exc:
            raise params.ParamError('--params-file', '{!r}: {}'.format(path, exc)) from None
        except yaml.YAMLError as exc:
            raise params.ParamError('--params-file', '{!r} is not valid YAML: {}'.format(
                path, str(exc).replace('\n', ' '))) from None
        try:
            params.check_section(doc)
        except params.ParamError as exc:
            raise params.ParamError(exc.name, '{} (in {})'.format(exc.reason, path)) from None


def main(args: Sequence[str] | None = None) -> int:
    """Run the bridge node; exit code 2 on a bad parameter, naming it."""
    stop = StopSignals().install()  # first: a stop during start-up ends it cleanly, too
    argv = list(sys.argv if args is None else args)
    try:
        # Before rclpy.init: rcl parses the files itself and would end a file it cannot
        # read (not UTF-8, nested too deep) in a traceback, exit 1.
        _check_param_files(argv)
    except params.ParamError as exc:
        sys.stderr.write('{}: {}\n'.format(params.NODE_NAME, exc))
        stop.restore()
        return 2
    rclpy.init(args=argv)  # rclpy's handlers chain to ours: both see a stop signal
    node = None
    try:
        try:
            if not stop.stopping:
                node = stop_aware_start(BridgeNode, stop)
        except params.ParamError as exc:
            sys.stderr.write('{}: {}\n'.format(params.NODE_NAME, exc))
            sys.stderr.flush()
            return 2
        if node is not None and not stop.stopping:
            spin_until_shutdown(lambda: rclpy.spin(node), node.context)
    except KeyboardInterrupt:  # before the node spins
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        stop.restore()
    if stop.stopping:
        sys.stderr.write('{}: stopped ({})\n'.format(params.NODE_NAME, stop.name))
        sys.stderr.flush()
    return 0


if __name__ == '__main__':
    sys.exit(main())
