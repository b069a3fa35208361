"""The 'laptop' of test_fleet: drives several namespaced robots and watches their TF trees.

``python netns_fleet.py CONTROL STATUS r1 r2 ...``: every 50 ms it reads CONTROL (JSON,
robot -> the command to publish on /<robot>/cmd_vel: a number (linear.x) or a pair
[linear.x, angular.z]; absent or null: publish nothing for it) and
writes STATUS (JSON): per robot how many subscriptions its cmd_vel publisher matched, how many
commands it sent, and every (parent, child) transform heard on /<robot>/tf and
/<robot>/tf_static, so the test sees each robot's tree as a tf listener of that robot would.
SIGTERM or SIGINT end it.
"""

import json
import os
import signal
import sys
import time

from geometry_msgs.msg import Twist
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from tf2_msgs.msg import TFMessage

_STATIC = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def main(control: str, status: str, robots: list) -> int:
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(1))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('fleet_laptop')
    pubs = {r: node.create_publisher(Twist, '/{}/cmd_vel'.format(r), 10) for r in robots}
    sent = dict.fromkeys(robots, 0)
    edges = {r: set() for r in robots}

    def on_tf(robot):
        def cb(msg):
            for t in msg.transforms:
                edges[robot].add((t.header.frame_id, t.child_frame_id))
        return cb
    for r in robots:
        node.create_subscription(TFMessage, '/{}/tf'.format(r), on_tf(r), 100)
        node.create_subscription(TFMessage, '/{}/tf_static'.format(r), on_tf(r), _STATIC)
    word = {}
    try:
        while not stop:
            try:
                with open(control, encoding='utf-8') as f:
                    word = json.loads(f.read() or '{}')
            except (OSError, ValueError):
                pass
            for r, v in word.items():
                if r in pubs and v is not None:
                    msg = Twist()
                    vx, wz = (v, 0.0) if isinstance(v, (int, float)) else v
                    msg.linear.x = float(vx)
                    msg.angular.z = float(wz)
                    pubs[r].publish(msg)
                    sent[r] += 1
            tmp = status + '.tmp'
            with open(tmp, 'w', encoding='utf-8') as f:
                json.dump({r: {'matched': pubs[r].get_subscription_count(), 'sent': sent[r],
                               'edges': sorted(edges[r])} for r in robots}, f)
            os.replace(tmp, status)
            end = time.monotonic() + 0.05
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1], sys.argv[2], sys.argv[3:]))
