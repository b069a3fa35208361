"""Parameters of the ``m4k_bridge`` node: one table of specs, pure validation (no rclpy).

Every parameter is declared from :data:`SPECS`, schema Fields (:mod:`m4k_rt.schema`: name,
type, default, unit, description, range, read-only flag, extra check, derived source); the
node builds its ParameterDescriptors from them. ``config/bridge.yaml`` carries the defaults of
the bridge's own parameters under ``m4k_bridge: ros__parameters:``; a test keeps the two in
step.
:func:`validate` is what the node's on-set-parameters callback and the start-up check both
call, so a value is refused with the same reason whether it comes from a parameter file or
``ros2 param set``.

Parameters that restate a physical value of the layered configuration (:data:`DERIVED`: the
command timeout, velocity limits, sensor frames, port labels, robot description) have one
source, that configuration: :func:`derived_values` computes them from the merged document.
Bringup and the launch file pass them; a bridge started by hand loads the layered
configuration for them. They are not in ``bridge.yaml``, and the ``m4k_bridge:`` section of a
user overlay may not set them (:func:`check_not_derived` names the field to set instead).

Parameters that pick resources at start-up (runtime directory, ports, topic names, message
type of ``cmd_vel``, static sensor poses) are read-only: changing them would need a restart.
"""

from __future__ import annotations

import array
import dataclasses
import math
import re
from typing import Any, Callable, Mapping

from m4k_rt import description
from m4k_rt.control.params import control_params, ControlConfigError, ControlParams
from m4k_rt.schema import ConfigError, Field

__all__ = [
    'BridgeParams', 'DERIVED', 'NODE_NAME', 'ParamError', 'ParamSpec', 'PORT_ROLES', 'SPECS',
    'TOPIC_ROLES', 'check_not_derived', 'check_section', 'derived_values', 'flatten_section',
    'from_values', 'nest', 'parse_port', 'spec', 'validate',
]

NODE_NAME = 'm4k_bridge'
PORT_ROLES = ('status', 'cmd', 'imu_out', 'led_in', 'sonar_out', 'lrf_out')
TOPIC_ROLES = ('cmd_vel', 'led', 'odom', 'imu', 'scan', 'sonar', 'diagnostics', 'rt_status',
               'e_stop', 'joint_states', 'robot_description', 'e_stop_state', 'cmd_vel_out',
               'motor_fault')
# Topics whose ROS convention is absolute (tf2_ros, robot_state_publisher and the diagnostic
# aggregator use /tf, /tf_static, /diagnostics): a namespace must not split them off.
_ABSOLUTE_TOPICS = {'diagnostics': '/diagnostics'}
SONAR_NO_ECHO = ('positive_infinity', 'max_range')
AUTO = 'auto'   # enable_stamped_cmd_vel: the type of the first cmd_vel publisher

_TOPIC = re.compile(r'^~?/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$')
_FRAME = re.compile(r'^[A-Za-z_][A-Za-z0-9_./-]*$')
_LABEL = re.compile(r'^[A-Za-z0-9_][A-Za-z0-9_.-]{0,31}$')


class ParamError(ConfigError):
    """A bridge parameter has a wrong value; ``name`` is the parameter, ``reason`` why."""

    def __init__(self, name: str, reason: str) -> None:
        super().__init__('parameter {!r}: {}'.format(name, reason))
        self.path = self.name = name
        self.reason = reason


# Parameter -> the field of the layered configuration it is derived from (one source).
DERIVED: dict[str, str] = {
    'cmd_vel_timeout': 'control.cmd_vel_timeout',
    'max_linear_velocity': 'control.linear.max_velocity',
    'max_angular_velocity': 'control.angular.max_velocity',
    'imu_frame': 'robot.sensors.imu.frame',
    'laser_frame': 'robot.sensors.laser.frame',
    'sonar_frame': 'robot.sensors.sonar.frame',
    **{'ports.' + role: 'ports.' + role for role in PORT_ROLES},
    'robot_description': 'robot (with control.wheel_radius and control.track_width)',
    'runtime_group': 'runtime.group',
}



@dataclasses.dataclass(frozen=True)
class ParamType:
    """One parameter type, as each side names it."""

    schema: str                   # the schema Field's type
    python: tuple[type, ...]      # the Python values of that type (bool before int: a subclass)
    ros: str                      # rclpy's name, as its messages spell it
    descriptor: str               # the rcl_interfaces ParameterType constant


# The one table of parameter types: ParamSpec, the rclpy type check (validate) and the ROS
# descriptors (m4k_bridge.descriptors) all read it. A list is a double[] unless its Field
# says str[] (the live view's lists).
PARAM_TYPES: tuple[ParamType, ...] = (
    ParamType('bool', (bool,), 'bool', 'PARAMETER_BOOL'),
    ParamType('int', (int,), 'int', 'PARAMETER_INTEGER'),
    ParamType('float', (float,), 'double', 'PARAMETER_DOUBLE'),
    ParamType('str', (str,), 'string', 'PARAMETER_STRING'),
    ParamType('float[]', (list, tuple, array.array), 'double[]', 'PARAMETER_DOUBLE_ARRAY'),
    ParamType('str[]', (list, tuple), 'string[]', 'PARAMETER_STRING_ARRAY'),
)


def param_type(value: Any) -> ParamType | None:
    """Return the type of a parameter value (the first row it is an instance of), or None."""
    for t in PARAM_TYPES:
        if isinstance(value, t.python):
            return t
    return None


def ParamSpec(name: str, default: Any, description: str, lo: float | None = None,  # noqa: N802
              hi: float | None = None, read_only: bool = False, length: int | None = None,
              check: Callable[[Any], str | None] | None = None, unit: str = '') -> Field:
    """Return the schema Field of one bridge parameter (type from its default, unit, source)."""
    t = param_type(default)
    if t is None:
        raise TypeError('parameter {!r}: no ROS parameter type for its default {!r}'.format(
            name, default))
    return Field(t.schema, default, description, unit=unit, lo=lo, hi=hi,
                 read_only=read_only, length=length, check=check,
                 derived_from=DERIVED.get(name, ''), name=name)


def _topic(v: Any) -> str | None:
    if not _TOPIC.match(v):
        return 'not a valid ROS topic name: {!r}'.format(v)
    return None


def _frame(v: Any) -> str | None:
    if not _FRAME.match(v):
        return 'not a valid frame id (letters, digits, _ . / -; not empty): {!r}'.format(v)
    return None


def _frame_or_empty(v: Any) -> str | None:
    return None if v == '' else _frame(v)


def _prefix(v: Any) -> str | None:
    if v and not _FRAME.match(v):
        return "not a valid frame prefix (letters, digits, _ . / -) or '': {!r}".format(v)
    return None


def _no_echo(v: Any) -> str | None:
    if v not in SONAR_NO_ECHO:
        return 'expected one of {}, got {!r}'.format(', '.join(SONAR_NO_ECHO), v)
    return None


def _bool_or_auto(v: Any) -> str | None:
    if isinstance(v, bool) or v == AUTO:
        return None
    return 'expected true, false or {}, got {!r}'.format(AUTO, v)


def _port(v: Any) -> str | None:
    if not (v.isdigit() or _LABEL.match(v)):
        return 'expected an XDDP port label or number, got {!r}'.format(v)
    return None


def _abs_dir(v: Any) -> str | None:
    if v and not v.startswith('/'):
        return "expected an absolute path or '' (the default directory), got {!r}".format(v)
    return None


def _runtime_dir(v: Any) -> str | None:
    if v and not v.startswith('/'):
        return "expected an absolute path or '' (default runtime directory), got {!r}".format(v)
    return None


_COV = 'variance, must be >= 0'
_CONTROL = ControlParams()   # the control section's defaults: derived parameters start there
SPECS: tuple[Field, ...] = (
    ParamSpec('runtime_dir', '', 'XDDP runtime directory holding the port sockets; empty: '
              '$M4K_RUNTIME_DIR, $XDG_RUNTIME_DIR/m4k, /run/m4k as root, else /tmp/m4k-<uid>. '
              'Must be the one the RT process uses, or no port ever links.',
              read_only=True, check=_runtime_dir),
    ParamSpec('runtime_group', '', 'Group of the runtime directory (derived: runtime.group). '
              'Before linking, the bridge checks the directory as the RT side does: not a '
              'symlink, owned by this user (root, or a member of this group), mode 0700 '
              '(0770 with this group); a directory that fails is refused (exit 2) rather than '
              'linked to sockets someone else could have planted.', read_only=True),
    *(ParamSpec('ports.' + role, role, 'XDDP port label (or number) of the RT side for {!r}. '
                'Derived: the label {!r} of the ports section (config/m4k.yaml); a wrong one '
                'never links, and the bridge reports the RT process lost.'.format(role, role),
                read_only=True, check=_port)
      for role in PORT_ROLES),
    *(ParamSpec('topics.' + role, _ABSOLUTE_TOPICS.get(role, role),
                'Topic name for {}; {}'.format(role, (
                    'absolute, as the diagnostic aggregator and rqt_robot_monitor read it '
                    'whatever the namespace') if role in _ABSOLUTE_TOPICS else
                    'relative so namespaces and remaps apply.'), read_only=True, check=_topic)
      for role in TOPIC_ROLES),
    dataclasses.replace(ParamSpec(
        'enable_stamped_cmd_vel', False, 'Subscribe cmd_vel as geometry_msgs/TwistStamped '
        '(true) or Twist (false), or auto: as Twist until the first cmd_vel publisher shows, '
        'then with the type that publisher uses (logged once; a later publisher of the other '
        "type is reported like a fixed setting's). Nav2 Jazzy and teleop publish Twist; Nav2 "
        "Kilted and ros2_controllers TwistStamped; the name is Nav2 and TurtleBot3's. A "
        'publisher of the other type never matches: the bridge reports it (cmd_vel diagnostic '
        'WARN, one log line naming both types). true, false or auto.', read_only=True,
        check=_bool_or_auto), type='any'),
    ParamSpec('use_stamped_vel', False, 'Deprecated alias of enable_stamped_cmd_vel (the '
              'old diff_drive_controller name, gone in Jazzy); true still works, with a '
              'warning at start-up.', read_only=True),
    ParamSpec('tf_namespaced', False, 'Publish tf and tf_static relative to the node namespace '
              "('tf', 'tf_static': /r1/tf under namespace r1) instead of the absolute /tf and "
              '/tf_static every tf2 listener reads by default. Only for setups that remap '
              '/tf:=tf in every node of the namespace (one tf tree per robot).',
              read_only=True),
    ParamSpec('frame_prefix', '', "Prefix of every frame id the bridge publishes (odom, tf, "
              "sensor headers), e.g. 'r1/' for two robots on one /tf; as "
              "robot_state_publisher's frame_prefix. robot_description keeps the bare names. "
              "Empty: none.", read_only=True, check=_prefix),
    ParamSpec('cmd_vel_timeout', _CONTROL.cmd_vel_timeout, 'Seconds after the last cmd_vel '
              'after which the input is reported idle in diagnostics. Derived: '
              'control.cmd_vel_timeout, on which the RT actuator brakes (the bridge never '
              'repeats or synthesizes commands); a different value makes diagnostics call the '
              'input idle before or after the robot brakes.', lo=0.0, hi=60.0, unit='s'),
    ParamSpec('max_linear_velocity', _CONTROL.linear.max_velocity, 'Linear speed limit [m/s]; '
              'cmd_vel beyond it is clamped and counted. Derived: control.linear.max_velocity '
              '(the RT limiter applies it again); lower it at run time to slow a session down.',
              lo=0.0, hi=10.0, unit='m/s'),
    ParamSpec('max_angular_velocity', _CONTROL.angular.max_velocity, 'Angular speed limit '
              '[rad/s]; cmd_vel beyond it is clamped and counted. Derived: '
              'control.angular.max_velocity.', lo=0.0, hi=20.0, unit='rad/s'),
    ParamSpec('odom_frame', 'odom', 'Frame id of odometry (REP-105 odom).', check=_frame),
    ParamSpec('base_frame', 'base_link', 'The body link (REP-105 base_link, on the wheel axle) '
              'the sensors, wheels and casters hang from in the generated robot description; '
              "odometry's child frame when footprint_frame is empty.", check=_frame),
    ParamSpec('footprint_frame', 'base_footprint', 'Child frame id of odometry and of the odom '
              'tf (as TurtleBot3 and Kobuki): the ground projection of base_frame, root of the '
              'generated robot description, base_frame the wheel radius above it. Empty: '
              'base_frame is the child and the root.', check=_frame_or_empty),
    ParamSpec('imu_frame', 'imu_link', 'Frame id of imu messages (REP-145). Derived: '
              'robot.sensors.imu.frame, a link of robot_description; another value does not '
              'connect to odom in tf.', check=_frame),
    ParamSpec('laser_frame', 'laser', 'Frame id of scan messages. Derived: '
              'robot.sensors.laser.frame.', check=_frame),
    ParamSpec('sonar_frame', 'sonar_link', 'Frame id of sonar messages. Derived: '
              'robot.sensors.sonar.frame.', check=_frame),
    ParamSpec('publish_tf', True, 'Broadcast odom -> base_link on tf. Turn off when another '
              'node (an EKF fusing odom and imu) publishes that transform.', read_only=True),
    ParamSpec('publish_robot_state', True, "Do robot_state_publisher's job: the description's "
              'fixed joints (sensors, casters) on tf_static and the wheel links on tf. Turn off '
              'when robot_state_publisher runs, or every transform has two publishers.',
              read_only=True),
    ParamSpec('robot_description', '', 'URDF published on robot_description (transient '
              'local); its fixed joints are the tf_static transforms and its wheel joints '
              'name joint_states. Derived: generated from the layered configuration '
              '(config/robot.yaml + control.wheel_radius/track_width); empty: the same.',
              read_only=True),
    ParamSpec('odom_pose_covariance_diagonal', [0.001, 0.001, 1.0e+6, 1.0e+6, 1.0e+6, 0.01],
              'Diagonal of the odometry pose covariance (x, y, z [m^2], roll, pitch, yaw '
              '[rad^2]); huge values mark the unobserved planar-robot axes. ' + _COV,
              lo=0.0, hi=1.0e9, length=6, unit='m^2, rad^2'),
    ParamSpec('odom_twist_covariance_diagonal', [0.001, 0.001, 1.0e+6, 1.0e+6, 1.0e+6, 0.01],
              'Diagonal of the odometry twist covariance (vx, vy, vz [m^2/s^2], wx, wy, wz '
              '[rad^2/s^2]). vy is a measurement, not an unknown: a differential drive cannot '
              'move sideways, so the published vy = 0 carries about the variance of vx (wheel '
              'slip), and an EKF fusing it (the robot_localization recipe) keeps its lateral '
              'velocity at zero; 1e6 would make that fusion a no-op. ' + _COV,
              lo=0.0, hi=1.0e9, length=6, unit='m^2/s^2, rad^2/s^2'),
    ParamSpec('imu_orientation_covariance_diagonal', [0.0003, 0.0003, 0.003],
              'Diagonal of the imu orientation covariance [rad^2] (roll, pitch, yaw). ' + _COV,
              lo=0.0, hi=1.0e9, length=3, unit='rad^2'),
    ParamSpec('imu_angular_velocity_covariance_diagonal', [0.0001, 0.0001, 0.0001],
              'Diagonal of the imu angular velocity covariance [rad^2/s^2]. ' + _COV,
              lo=0.0, hi=1.0e9, length=3, unit='rad^2/s^2'),
    ParamSpec('imu_linear_acceleration_covariance_diagonal', [0.01, 0.01, 0.01],
              'Diagonal of the imu linear acceleration covariance [m^2/s^4]. ' + _COV,
              lo=0.0, hi=1.0e9, length=3, unit='m^2/s^4'),
    ParamSpec('sonar_field_of_view', 0.2618, 'Sonar cone opening [rad] (US-100: about 15 deg).',
              lo=0.01, hi=math.pi, unit='rad'),
    ParamSpec('sonar_min_range', 0.02, 'Sonar minimum range [m] (US-100: 2 cm).',
              lo=0.0, hi=10.0, unit='m'),
    ParamSpec('sonar_no_echo', 'positive_infinity', "What sonar range says 'nothing within "
              "range': 'positive_infinity' "
              "(REP-117 +inf; Nav2's range layer ignores such a reading) or 'max_range' "
              "(sonar_max_range, which Nav2's range layer clears with clear_on_max_reading: "
              'true). Faulty readings (timeout, bad echo) are never published: dropped and '
              'counted (sonar diagnostic).', check=_no_echo),
    ParamSpec('sonar_max_range', 4.5, 'Sonar maximum range [m] (US-100: 4.5 m); must exceed '
              'sonar_min_range.', lo=0.01, hi=20.0, unit='m'),
    ParamSpec('stats_window', 10.0, 'Sliding window of RT timing samples behind rt_status, '
              'and of the driver host drops judged in diagnostics [s].', lo=1.0, hi=600.0,
              unit='s'),
    ParamSpec('rt_status_period', 1.0, 'Publication period of rt_status [s].',
              lo=0.05, hi=60.0, unit='s'),
    ParamSpec('diagnostics_period', 1.0, 'Publication period of diagnostics [s] (REP-107: 1 Hz).',
              lo=0.05, hi=60.0, unit='s'),
    ParamSpec('flight_recorder.enabled', True, 'Keep the last seconds of commands, odometry, '
              'guard/supervisor flags, faults and RT timing in memory and write them as a bag '
              'on an e-stop, guard stop, motor fault, deadline miss or device fault '
              '(docs/recording.md). False: no ring, no subscriptions, no dumps -- and no record '
              'of the next incident.', read_only=True),
    ParamSpec('flight_recorder.seconds', 10.0, 'Seconds before a trigger that a flight '
              'recorder dump holds (the ring keeps these plus post_seconds), unless max_bytes '
              'cuts them shorter.', lo=1.0, hi=120.0, read_only=True, unit='s'),
    ParamSpec('flight_recorder.post_seconds', 2.0, 'Seconds after a trigger the dump waits '
              'for, so the stop itself is in it. 0: the dump ends at the trigger.',
              lo=0.0, hi=30.0, read_only=True, unit='s'),
    ParamSpec('flight_recorder.max_bytes', 8 * 1024 * 1024, "Memory cap of the flight "
              "recorder's ring (payload + 160 bytes per message); past it the oldest messages "
              'go first and the dump covers less than seconds (its metadata counts the '
              'evictions). At the default topics (about 30 KiB/s) 8 MiB is minutes.',
              lo=65536, hi=1 << 30, read_only=True, unit='bytes'),
    ParamSpec('flight_recorder.min_interval', 30.0, 'At most one dump per trigger kind in this '
              'many seconds; a trigger in between is only noted in the ring '
              '(flight_recorder/trigger, dumped: no) and so in the next dump. Lower: more '
              'bags from a fault that repeats.',
              lo=1.0, hi=86400.0, unit='s'),
    ParamSpec('flight_recorder.directory', '', 'Directory the dumps go to, one bag directory '
              "flight_<UTC time>_<trigger> each; '' = $XDG_STATE_HOME/m4k/flight_recorder "
              '(~/.local/state/m4k/flight_recorder). Kept within max_disk_bytes and '
              'max_age_days.', read_only=True, check=_abs_dir),
    ParamSpec('flight_recorder.max_disk_bytes', 256 * 1024 * 1024, 'Disk cap of the flight '
              "recorder's dumps (their files' blocks): after each dump the oldest are removed "
              'until the rest fit; the newest dump is always kept. Only flight_* bag '
              'directories are counted or removed.', lo=1 << 20, hi=1 << 40, read_only=True,
              unit='bytes'),
    ParamSpec('flight_recorder.max_age_days', 30.0, 'Dumps older than this (by the UTC time '
              'in their name) are removed after each dump and at start. 0: no age limit.',
              lo=0.0, hi=3650.0, read_only=True, unit='days'),
    ParamSpec('rt_stale_timeout', 3.0, 'Seconds without any datagram from the RT process '
              'after which it is reported lost (diagnostics STALE, one log line).',
              lo=0.1, hi=600.0, unit='s'),
    ParamSpec('relink_interval', 0.5, 'Seconds between attempts to re-open a port whose RT '
              'side is gone.', lo=0.01, hi=60.0, read_only=True, unit='s'),
    ParamSpec('reset_odometry_timeout', 1.0, 'Seconds ~/reset_odometry and ~/set_pose wait '
              "for the RT actuator's acknowledgement before they answer success=false.",
              lo=0.05, hi=60.0, unit='s'),
    ParamSpec('e_stop_timeout', 1.0, 'Seconds ~/e_stop waits for the RT latch (ODOMETRY '
              'flags) to show the requested state before it answers success=false.',
              lo=0.05, hi=60.0, unit='s'),
)

_BY_NAME = {s.name: s for s in SPECS}


def spec(name: str) -> Field:
    """Return the spec of parameter ``name`` (KeyError when unknown)."""
    return _BY_NAME[name]


def derived_values(doc: Mapping[str, Any], base_frame: str = 'base_link',
                   footprint_frame: str = 'base_footprint') -> dict[str, Any]:
    """Return the :data:`DERIVED` parameters of a merged configuration document.

    Sections the document lacks give nothing (``control`` its defaults, as the RT actuator
    uses them). Raise :class:`ParamError` naming the parameter and the source field when the
    source is unusable.
    """
    out: dict[str, Any] = {}
    try:
        control = control_params(doc.get('control'))
    except ControlConfigError as exc:
        raise ParamError('cmd_vel_timeout', 'derived from the control section: {}'.format(
            exc)) from None
    out['cmd_vel_timeout'] = control.cmd_vel_timeout
    out['max_linear_velocity'] = control.linear.max_velocity
    out['max_angular_velocity'] = control.angular.max_velocity
    runtime = doc.get('runtime')
    if isinstance(runtime, Mapping):
        out['runtime_group'] = runtime.get('group') or ''
    ports = doc.get('ports')
    if isinstance(ports, Mapping):
        for role in PORT_ROLES:
            if role not in ports:
                raise ParamError('ports.' + role, 'the ports section (config/m4k.yaml) has no '
                                 'label {!r}, which the RT side binds for the bridge'.format(role))
            out['ports.' + role] = role
    if 'robot' in doc:
        try:
            robot = description.model(doc, base_frame, footprint_frame)
        except description.DescriptionError as exc:
            raise ParamError('robot_description', str(exc)) from None
        out['robot_description'] = description.urdf(robot)
        for sensor in description.SENSORS:
            out['{}_frame'.format(sensor)] = robot.sensors[sensor].frame
    for name, value in out.items():
        reason = validate(name, value)
        if reason is not None:
            raise ParamError(name, '{} (derived from {})'.format(reason, DERIVED[name]))
    return out


def check_not_derived(names: Any) -> None:
    """Raise ParamError for the first derived parameter in ``names``, naming its source."""
    for name in names:
        if name in DERIVED:
            raise ParamError(name, 'derived from {} of the layered configuration: set it '
                             'there (one source per value)'.format(DERIVED[name]))


def _kind(v: Any) -> str:
    t = param_type(v)
    return type(v).__name__ if t is None else t.ros


def validate(name: str, value: Any) -> str | None:
    """Return why ``value`` is wrong for parameter ``name``, or None when it is fine.

    rclpy's typing comes first (a parameter keeps the type of its default, and an integer is
    not a double); the value is then judged by its schema Field (:meth:`Field.problem`), as
    the configuration files are.
    """
    s = _BY_NAME.get(name)
    if s is None:
        return 'unknown parameter (known: {})'.format(', '.join(sorted(_BY_NAME)))
    if s.type != 'any':          # 'any': a bool or a keyword (enable_stamped_cmd_vel: auto)
        want = _kind(s.default)
        got = _kind(value)
        if want == 'double' and got == 'int':
            # rclpy types parameters by their YAML spelling and refuses an integer for a double.
            return 'expected a double, got the integer {!r} (write {!r})'.format(
                value, float(value))
        if want != got:
            return 'expected a {}, got {!r}'.format(want, value)
    return s.problem(list(value) if isinstance(value, array.array) else value)


@dataclasses.dataclass(frozen=True)
class BridgeParams:
    """Validated parameter values, in the shapes the node uses."""

    values: Mapping[str, Any]

    def __getitem__(self, name: str) -> Any:
        """Return the value of parameter ``name``."""
        return self.values[name]

    def port(self, role: str) -> int | str:
        """Return the port number or label for ``role``."""
        return parse_port(self.values['ports.' + role])

    def topic(self, role: str) -> str:
        """Return the topic name for ``role``."""
        return self.values['topics.' + role]

    @property
    def stamped_cmd_vel(self) -> bool:
        """Return whether cmd_vel starts as TwistStamped (either name of the switch)."""
        return (self.values['enable_stamped_cmd_vel'] is True
                or bool(self.values['use_stamped_vel']))

    @property
    def auto_cmd_vel(self) -> bool:
        """Return whether the cmd_vel type follows its first publisher (``auto``)."""
        return (self.values['enable_stamped_cmd_vel'] == AUTO
                and not self.values['use_stamped_vel'])

    @property
    def odom_child(self) -> str:
        """Return the child frame of odometry (unprefixed): the footprint, else base_frame."""
        return self.values['footprint_frame'] or self.values['base_frame']

    def frame(self, name: str) -> str:
        """Return the published id of frame ``name``: ``frame_prefix`` + name."""
        return self.values['frame_prefix'] + name


def parse_port(value: str) -> int | str:
    """Return a port given as a string: a number when all digits, else the label."""
    return int(value) if value.isdigit() else value


def _cross_check(values: Mapping[str, Any]) -> None:
    lo, hi = values['sonar_min_range'], values['sonar_max_range']
    if not hi > lo:
        raise ParamError('sonar_max_range', 'must exceed sonar_min_range ({!r}), got {!r}'.format(
            lo, hi))


def from_values(values: Mapping[str, Any]) -> BridgeParams:
    """Validate a complete name -> value mapping (defaults filled in) into BridgeParams."""
    full = {s.name: s.default for s in SPECS}
    full.update(values)
    for name, value in full.items():
        reason = validate(name, value)
        if reason is not None:
            raise ParamError(name, reason)
    for s in SPECS:
        if isinstance(s.default, float):
            full[s.name] = float(full[s.name])
        elif isinstance(s.default, list):
            full[s.name] = [float(x) for x in full[s.name]]
    _cross_check(full)
    return BridgeParams(full)


def _flatten(prefix: str, m: Mapping[str, Any], out: dict[str, Any]) -> None:
    # ROS parameter files nest dotted names: {'ports': {'cmd': 'cmd'}} is 'ports.cmd'.
    for k, v in m.items():
        name = '{}.{}'.format(prefix, k) if prefix else str(k)
        if isinstance(v, Mapping):
            _flatten(name, v, out)
        else:
            out[name] = v


def check_section(doc: Any, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Validate the parameters of ``node_name`` in a parsed ROS parameter file.

    Looks at the ``<node_name>`` and ``/**`` sections (with or without a leading ``/``);
    returns the flat name -> value mapping and raises ParamError naming the first bad one.
    """
    found = flatten_section(doc, node_name)
    for name, value in found.items():
        if name == 'use_sim_time':
            continue
        reason = validate(name, value)
        if reason is not None:
            raise ParamError(name, reason)
    return found


def nest(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Return dotted names as nested mappings, the layout of ROS parameter files."""
    out: dict[str, Any] = {}
    for name, value in flat.items():
        *parents, leaf = name.split('.')
        node = out
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return out


def flatten_section(doc: Any, node_name: str = NODE_NAME) -> dict[str, Any]:
    """Return the flat name -> value parameters of ``node_name`` in a parameter file."""
    if doc is None:
        return {}
    if not isinstance(doc, Mapping):
        raise ParamError('<file>', 'top level must be a mapping, got {!r}'.format(doc))
    found: dict[str, Any] = {}
    for key, section in doc.items():
        # '/ns/m4k_bridge' (launch_ros writes the fully qualified name), 'm4k_bridge', '/**'.
        if str(key).rsplit('/', 1)[-1] not in (node_name, '**'):
            continue
        if not isinstance(section, Mapping) or not isinstance(
                section.get('ros__parameters', {}), Mapping):
            raise ParamError(str(key), "expected a mapping with 'ros__parameters', got {!r}"
                             .format(section))
        flat: dict[str, Any] = {}
        _flatten('', section.get('ros__parameters') or {}, flat)
        wildcard = str(key).rsplit('/', 1)[-1] == '**'
        # A wildcard section also feeds other nodes: only its names known here are ours.
        found.update((k, v) for k, v in flat.items() if not wildcard or k in _BY_NAME)
    return found
