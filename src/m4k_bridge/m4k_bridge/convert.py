"""Conversions between m4k datagram payloads and ROS 2 messages (pure: no rclpy, no sockets).

Inputs are the payload NamedTuples of :mod:`m4k_rt.protocol` and plain numbers; outputs are
message objects of the common interface packages (those import the generated message classes
only, not the client library), or plain tuples for the reverse direction. Conventions:

* REP-103 units and axes, REP-105 frames (odom -> base_link), REP-145 for the IMU (a
  covariance whose first element is -1 marks an absent quantity);
* REP-117 for invalid ranges: +inf = nothing within range, NaN = erroneous reading (the
  scan; a sonar reading that is not a range is dropped instead, :func:`sonar_msg`);
* stamps: datagrams carry the sender's CLOCK_MONOTONIC; :func:`ros_stamp_ns` moves that
  instant onto the ROS clock by the age of the datagram, so a message is stamped when it was
  measured, not when the bridge got round to it.
"""

from __future__ import annotations

import math
from typing import Sequence

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, LaserScan, Range

from m4k_rt import protocol
from m4k_rt.rotation import quaternion_rpy

__all__ = [
    'NonFiniteCommand', 'covariance3',
    'covariance6', 'imu_msg', 'led_command', 'odometry_msg', 'odom_transform', 'quaternion_rpy',
    'ros_stamp_ns', 'scan_msg', 'sonar_msg', 'static_transform', 'time_msg', 'urg_range_m',
    'velocity_command',
]

# URG (SCIP 2.0) error codes: the table has one owner, m4k_rt.protocol.SCAN_ERROR_CODES (SCIP 2.0
# spec C-42-03320B, Table 3). Only code 0 ("object possibly at 22 m", i.e. nothing within the
# measurable range) is REP-117 +inf; every other code (< 20) is an erroneous reading: NaN.


class NonFiniteCommand(ValueError):
    """A command contained NaN or infinity and was rejected."""


def time_msg(ns: int) -> Time:
    """Return a builtin_interfaces/Time for ``ns`` nanoseconds."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def ros_stamp_ns(stamp_mono_ns: int, now_mono_ns: int, now_ros_ns: int) -> int:
    """Map a sender's CLOCK_MONOTONIC stamp onto the ROS clock.

    The datagram's age (``now_mono - stamp``) is subtracted from the ROS time now; a stamp
    from the future (clock skew between processes cannot happen on one host, but a bogus
    datagram can) is clamped to now.
    """
    age = now_mono_ns - stamp_mono_ns
    return now_ros_ns - age if age > 0 else now_ros_ns


def _diagonal_covariance(diagonal: Sequence[float], n: int) -> list[float]:
    """Return a row-major n x n covariance with ``diagonal`` (n variances) on its diagonal."""
    if len(diagonal) != n:
        raise ValueError('{0}x{0} covariance needs {0} variances, got {1!r}'.format(n, diagonal))
    out = [0.0] * (n * n)
    for i, v in enumerate(diagonal):
        out[i * (n + 1)] = float(v)
    return out


def covariance6(diagonal: Sequence[float]) -> list[float]:
    """Return a row-major 6x6 covariance with ``diagonal`` (6 variances) on its diagonal."""
    return _diagonal_covariance(diagonal, 6)


def covariance3(diagonal: Sequence[float]) -> list[float]:
    """Return a row-major 3x3 covariance with ``diagonal`` (3 variances) on its diagonal."""
    return _diagonal_covariance(diagonal, 3)


def odometry_msg(odom: protocol.Odometry, stamp_ns: int, frame_id: str, child_frame_id: str,
                 pose_cov: Sequence[float], twist_cov: Sequence[float]) -> Odometry:
    """Build nav_msgs/Odometry (pose in ``frame_id``, twist in ``child_frame_id``)."""
    msg = Odometry()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    msg.child_frame_id = child_frame_id
    p = msg.pose.pose
    p.position.x, p.position.y = odom.x, odom.y
    qx, qy, qz, qw = quaternion_rpy(0.0, 0.0, odom.yaw)
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = qx, qy, qz, qw
    msg.pose.covariance = covariance6(pose_cov)
    msg.twist.twist.linear.x = odom.v
    msg.twist.twist.angular.z = odom.w
    msg.twist.covariance = covariance6(twist_cov)
    return msg


def odom_transform(odom: protocol.Odometry, stamp_ns: int, frame_id: str,
                   child_frame_id: str) -> TransformStamped:
    """Build the odom -> base_link transform of an odometry estimate."""
    t = TransformStamped()
    t.header.stamp = time_msg(stamp_ns)
    t.header.frame_id = frame_id
    t.child_frame_id = child_frame_id
    t.transform.translation.x, t.transform.translation.y = odom.x, odom.y
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = quaternion_rpy(0.0, 0.0, odom.yaw)
    return t


def static_transform(parent: str, child: str, pose: Sequence[float],
                     stamp_ns: int) -> TransformStamped:
    """Build a static transform from a pose [x, y, z, roll, pitch, yaw] of child in parent."""
    if len(pose) != 6:
        raise ValueError('pose needs x, y, z, roll, pitch, yaw, got {!r}'.format(pose))
    t = TransformStamped()
    t.header.stamp = time_msg(stamp_ns)
    t.header.frame_id = parent
    t.child_frame_id = child
    tr = t.transform.translation
    tr.x, tr.y, tr.z = (float(v) for v in pose[:3])
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = quaternion_rpy(*(float(v) for v in pose[3:]))
    return t


def imu_msg(imu: protocol.Imu, stamp_ns: int, frame_id: str, orientation_cov: Sequence[float],
            gyro_cov: Sequence[float], accel_cov: Sequence[float]) -> Imu | None:
    """Build sensor_msgs/Imu (REP-145), or None for a sample the device marked not ready.

    With an invalid quaternion the orientation is reported absent (covariance[0] = -1) while
    angular velocity and acceleration are still published.
    """
    if imu.status == protocol.ImuStatus.NOT_READY:
        return None
    msg = Imu()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    if imu.status == protocol.ImuStatus.BAD_QUATERNION:
        msg.orientation.w = 1.0
        cov = [0.0] * 9
        cov[0] = -1.0
        msg.orientation_covariance = cov
    else:
        o = msg.orientation
        o.x, o.y, o.z, o.w = imu.qx, imu.qy, imu.qz, imu.qw
        msg.orientation_covariance = covariance3(orientation_cov)
    g = msg.angular_velocity
    g.x, g.y, g.z = imu.gx, imu.gy, imu.gz
    msg.angular_velocity_covariance = covariance3(gyro_cov)
    a = msg.linear_acceleration
    a.x, a.y, a.z = imu.ax, imu.ay, imu.az
    msg.linear_acceleration_covariance = covariance3(accel_cov)
    return msg


def urg_range_m(mm: int) -> float:
    """Return a URG range in metres; error codes (< 20 mm) become +inf or NaN (REP-117)."""
    if mm > protocol.SCAN_ERROR_CODE_MAX:
        return mm * 0.001
    return math.inf if mm in protocol.SCAN_FAR_CODES else math.nan


def scan_msg(scan: protocol.LaserScan, stamp_ns: int, frame_id: str) -> LaserScan:
    """Build sensor_msgs/LaserScan from the LASER_SCAN geometry and ranges (mm)."""
    msg = LaserScan()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    n = len(scan.ranges)
    msg.angle_min = scan.angle_min
    msg.angle_max = scan.angle_min + scan.angle_increment * max(n - 1, 0)
    msg.angle_increment = scan.angle_increment
    msg.time_increment = scan.time_increment
    msg.scan_time = scan.scan_time
    msg.range_min = scan.range_min
    msg.range_max = scan.range_max
    msg.ranges = [urg_range_m(mm) for mm in scan.ranges]
    return msg


def sonar_msg(sonar: protocol.Sonar, stamp_ns: int, frame_id: str, field_of_view: float,
              min_range: float, max_range: float,
              no_echo: str = 'positive_infinity') -> Range | None:
    """Build sensor_msgs/Range (ULTRASOUND), or None when the reading must not be published.

    No echo within range -> +inf (REP-117, ``no_echo='positive_infinity'``) or ``max_range``
    (``no_echo='max_range'``: what Nav2's range layer clears with ``clear_on_max_reading``).
    A timeout, a fault or a non-finite range gives None: Nav2's range layer lets NaN through
    its ``<`` / ``>`` checks, so an erroneous reading is dropped (the caller counts it).
    """
    if sonar.status == protocol.SONAR_OK:
        if not math.isfinite(sonar.range_m):
            return None
        value = sonar.range_m
    elif sonar.status == protocol.SONAR_NO_ECHO:
        value = max_range if no_echo == 'max_range' else math.inf
    else:
        return None
    msg = Range()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    msg.radiation_type = Range.ULTRASOUND
    msg.field_of_view = field_of_view
    msg.min_range = min_range
    msg.max_range = max_range
    msg.range = value
    return msg


def velocity_command(linear_x: float, angular_z: float, max_linear: float,
                     max_angular: float) -> tuple[float, float, bool]:
    """Return (linear_x, angular_z, clamped) within the limits.

    Raise NonFiniteCommand for NaN or infinite input: a bad command is rejected as a whole,
    never forwarded in part.
    """
    if not (math.isfinite(linear_x) and math.isfinite(angular_z)):
        raise NonFiniteCommand('cmd_vel with non-finite value: linear.x={!r} angular.z={!r}'
                               .format(linear_x, angular_z))
    v = min(max(linear_x, -max_linear), max_linear)
    w = min(max(angular_z, -max_angular), max_angular)
    return v, w, (v != linear_x or w != angular_z)


def led_command(r: float, g: float, b: float, a: float) -> tuple[int, int, int, int, int]:
    """Return the LED override (r, g, b, brightness, source) for a std_msgs/ColorRGBA.

    Channels are 0..1 (clamped); ``a`` is the brightness. ``a == 0`` releases the override
    (brightness 0, source 0: the RT LED task shows the robot state again).
    """
    if not all(math.isfinite(c) for c in (r, g, b, a)):
        raise NonFiniteCommand('led colour with non-finite value: {!r}'.format((r, g, b, a)))

    def byte(c: float) -> int:
        return int(round(min(max(c, 0.0), 1.0) * 255))

    if byte(a) == 0:
        return 0, 0, 0, 0, int(protocol.LedSource.STATE)
    return byte(r), byte(g), byte(b), byte(a), int(protocol.LedSource.OVERRIDE)
