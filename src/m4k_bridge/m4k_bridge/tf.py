"""The bridge's robot state: tf, tf_static, robot_description and joint_states (rclpy).

What robot_state_publisher and a diff-drive controller would publish for a mobile base, from
the ODOMETRY datagrams and the robot description (:mod:`m4k_rt.description`):

* ``robot_description`` (std_msgs/String, transient local): the URDF, once, with
  ``publish_robot_state`` (robot_state_publisher publishes it otherwise: one publisher);
* ``joint_states`` (sensor_msgs/JointState): both wheel joints' positions [rad] and velocities
  [rad/s] from the encoders, stamped like ``odom``;
* ``tf``: odom -> base_footprint (``publish_tf``; off when an EKF publishes it) and, with
  ``publish_robot_state``, the wheel links turned by their joint positions;
* ``tf_static`` (transient local, as tf2_ros's StaticTransformBroadcaster): every fixed joint of
  the description -- casters, laser, IMU, sonar -- with ``publish_robot_state``. Turn
  ``publish_robot_state`` off when robot_state_publisher runs (``ros2 launch ...
  robot_state_publisher:=true`` does), so no transform has two publishers.

Both go on the absolute ``/tf`` and ``/tf_static`` as tf2_ros's broadcasters do (a
namespaced bridge must not put odom -> base_footprint on ``/r1/tf`` while robot_state_publisher
puts the sensor frames on ``/tf_static``: two trees); ``tf_namespaced`` chooses the relative
names. ``frame_prefix`` is prepended to every frame id (robot_state_publisher's parameter of
the same name), so two robots can share one tf tree.

tf2_msgs is not on PyPI: on the wheels path the workspace builds a type-identical tf2_msgs
(``compat/tf2_msgs``, same type hash). Without any tf2_msgs, tf is off with one notice.
"""

from __future__ import annotations

import math
from typing import Any, Sequence

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from m4k_bridge import convert
from m4k_rt import description, protocol

try:
    from tf2_msgs.msg import TFMessage
except ImportError:  # pragma: no cover - no tf2_msgs at all (neither ROS nor compat/)
    TFMessage = None

__all__ = ['LATCHED', 'RobotStatePublisher', 'TFMessage', 'joint_transform']

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
_TF_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)  # TransformBroadcaster
_STATE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)


def _quat_mul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz)


def joint_transform(joint: description.Joint, position: float, stamp_ns: int) -> Any:
    """Return the TransformStamped of a revolute/continuous joint at ``position`` [rad]."""
    t = convert.static_transform(joint.parent, joint.child, [*joint.xyz, *joint.rpy], stamp_ns)
    ax, ay, az = joint.axis
    norm = math.sqrt(ax * ax + ay * ay + az * az) or 1.0
    s = math.sin(0.5 * position) / norm
    r = t.transform.rotation
    r.x, r.y, r.z, r.w = _quat_mul((r.x, r.y, r.z, r.w),
                                   (ax * s, ay * s, az * s, math.cos(0.5 * position)))
    return t


class RobotStatePublisher:
    """Publish the robot description, joint states and transforms of one bridge node."""

    def __init__(self, node: Node, urdf: str, odom_frame: str, base_frame: str,
                 publish_tf: bool, publish_robot_state: bool, topic_joint_states: str,
                 topic_description: str, frame_prefix: str = '',
                 tf_namespaced: bool = False) -> None:
        """Parse the description and create the publishers (DescriptionError if unusable).

        ``base_frame``: odometry's child frame (the footprint); frames are given unprefixed.
        """
        self.node = node
        self.prefix = frame_prefix
        self.set_frames(odom_frame, base_frame)
        self.fixed = description.fixed_joints(urdf)
        self.wheels = description.wheel_joints(urdf)
        self.links = {j.child for j in description.joints(urdf)} | {
            j.parent for j in description.joints(urdf)}
        self.names = [j.name for j in self.wheels]
        self._desc_pub = None
        if publish_robot_state:
            self._desc_pub = node.create_publisher(String, topic_description, LATCHED)
            self._desc_pub.publish(String(data=urdf))
        self._joint_pub = node.create_publisher(JointState, topic_joint_states, _STATE_QOS)
        self.tf_pub = self.static_pub = None
        if (publish_tf or publish_robot_state) and TFMessage is None:
            node.get_logger().info(
                'tf is off: no tf2_msgs is importable (a full ROS install has it; on the '
                'wheels path `make build` builds compat/tf2_msgs). odom is still published.')
            return
        self.publish_tf = publish_tf
        self.publish_robot_state = publish_robot_state
        tf_topic, static_topic = ('tf', 'tf_static') if tf_namespaced else ('/tf', '/tf_static')
        if publish_tf or publish_robot_state:
            self.tf_pub = node.create_publisher(TFMessage, tf_topic, _TF_QOS)
        if publish_robot_state:
            self.static_pub = node.create_publisher(TFMessage, static_topic, LATCHED)
            stamp = node.get_clock().now().nanoseconds
            self.static_pub.publish(TFMessage(transforms=[
                self._prefixed(convert.static_transform(j.parent, j.child, [*j.xyz, *j.rpy],
                                                        stamp))
                for j in self.fixed]))

    def set_frames(self, odom_frame: str, base_frame: str) -> None:
        """Take new (unprefixed) odom / child frame ids, e.g. after a run-time parameter change."""
        self.odom_frame, self.base_frame = odom_frame, base_frame

    def _prefixed(self, t: Any) -> Any:
        if self.prefix:
            t.header.frame_id = self.prefix + t.header.frame_id
            t.child_frame_id = self.prefix + t.child_frame_id
        return t

    def on_odometry(self, odom: protocol.Odometry, stamp_ns: int) -> None:
        """Publish joint_states and the tf of one ODOMETRY, stamped like odom."""
        js = JointState()
        js.header.stamp = convert.time_msg(stamp_ns)
        js.name = self.names
        js.position = [odom.left_position, odom.right_position]
        js.velocity = [odom.left_wheel, odom.right_wheel]
        self._joint_pub.publish(js)
        if self.tf_pub is None:
            return
        transforms = []
        if self.publish_tf:
            transforms.append(convert.odom_transform(odom, stamp_ns, self.odom_frame,
                                                     self.base_frame))
        if self.publish_robot_state:
            positions = (odom.left_position, odom.right_position)
            transforms += [joint_transform(j, pos, stamp_ns)
                           for j, pos in zip(self.wheels, positions, strict=True)]
        transforms = [self._prefixed(t) for t in transforms]
        self.tf_pub.publish(TFMessage(transforms=transforms))
