"""What a live view client may publish, decided by the node before it imports anything.

In-process rclpy (a node of its own per test): the topic allow-list is checked before the
client's type is imported; the 3D panel's nav topics are accepted without an alert and
published only with ``nav_goals:=true``; a service is advertised in the spec's current form.
"""

from __future__ import annotations

import importlib
import time
from typing import Any

from geometry_msgs.msg import PoseStamped
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message

from m4k_bridge.foxglove.node import FoxgloveNode

pytestmark = pytest.mark.allow_leaks('fds')  # FastDDS keeps its sockets for the process


class _Texts:
    def __init__(self) -> None:
        self.sent: list[tuple[int, str]] = []

    def __call__(self, client: int, text: str) -> None:
        self.sent.append((client, text))


def _node(*params: str) -> FoxgloveNode:
    args = ['x', '--ros-args', '-p', 'port:=0']
    for p in params:
        args += ['-p', p]
    rclpy.init(args=args)
    node = FoxgloveNode()
    # These tests call the handler directly, as the server would for a drive client.
    node.server.client_right = lambda client: 'drive'  # type: ignore[method-assign]
    node.server.client_name = lambda client: 'client {}'.format(client)  # type: ignore
    return node


def _close(node: FoxgloveNode, *others: Any) -> None:
    for n in others:
        n.destroy_node()
    node.destroy_node()
    rclpy.try_shutdown()


def test_a_topic_outside_client_topics_is_refused_before_its_type_is_imported(monkeypatch):
    node = _node()
    imported: list[str] = []
    real = importlib.import_module

    def spy(name: str, *a: Any) -> Any:
        imported.append(name)
        return real(name, *a)

    try:
        monkeypatch.setattr(importlib, 'import_module', spy)
        why = node.on_client_advertise(1, {'id': 1, 'topic': '/odom', 'encoding': 'cdr',
                                           'schemaName': 'evil_pkg/msg/Payload'})
        assert why is not None and 'clients may publish only on' in why
        why = node.on_client_advertise(1, {'id': 2, 'topic': '/cmd_vel', 'encoding': 'cdr',
                                           'schemaName': 'os.path/msg/x;y'})
        assert why is not None and 'not a message type name' in why
        assert imported == []
    finally:
        monkeypatch.undo()
        _close(node)


def test_nav_topics_are_accepted_silently_and_not_published_while_nav_goals_is_false():
    node = _node()
    texts = _Texts()
    node.server.send_text = texts      # type: ignore[method-assign]
    try:
        for i, (topic, tname) in enumerate((
                ('/goal_pose', 'geometry_msgs/PoseStamped'),
                ('/clicked_point', 'geometry_msgs/msg/PointStamped'),
                ('/initialpose', 'geometry_msgs/msg/PoseWithCovarianceStamped'))):
            assert node.on_client_advertise(3, {'id': i, 'topic': topic, 'encoding': 'cdr',
                                                'schemaName': tname}) is None
        assert texts.sent == []
        # The wrong type on a nav topic is refused, naming the one it takes.
        why = node.on_client_advertise(3, {'id': 9, 'topic': '/goal_pose', 'encoding': 'cdr',
                                           'schemaName': 'geometry_msgs/msg/Twist'})
        assert why == '/goal_pose: expects geometry_msgs/msg/PoseStamped, not ' \
            'geometry_msgs/msg/Twist'
        node.on_client_message(3, 0, serialize_message(PoseStamped()))
        assert len(texts.sent) == 1 and 'nav_goals' in texts.sent[0][1]
        assert node.inert_messages == 1
        node._run_actions()
        assert node.count_publishers('/goal_pose') == 0
    finally:
        _close(node)


def test_with_nav_goals_a_goal_from_the_3d_panel_reaches_the_nav_stack():
    node = _node('nav_goals:=true')
    reader = rclpy.create_node('nav_reader')
    got: list[float] = []
    reader.create_subscription(PoseStamped, 'goal_pose', lambda m: got.append(m.pose.position.x),
                               QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(reader)

    def spin_until(cond: Any, what: str, timeout: float = 20.0) -> None:
        end = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < end, what
            ex.spin_once(timeout_sec=0.05)

    try:
        assert node.on_client_advertise(4, {'id': 1, 'topic': '/goal_pose', 'encoding': 'cdr',
                                            'schemaName': 'geometry_msgs/msg/PoseStamped'}) \
            is None
        spin_until(lambda: node.count_publishers('/goal_pose') == 1, 'no publisher')
        spin_until(lambda: reader.count_publishers('/goal_pose') == 1, 'not matched')
        goal = PoseStamped()
        goal.header.frame_id = 'odom'
        goal.pose.position.x = 1.5
        deadline = time.monotonic() + 20.0
        while not got:
            assert time.monotonic() < deadline, 'the goal never arrived'
            node.on_client_message(4, 1, serialize_message(goal))
            spin_until(lambda: True, '')
            ex.spin_once(timeout_sec=0.2)
        assert got[0] == 1.5
    finally:
        ex.shutdown()
        _close(node, reader)
