"""The 'laptop' of test_two_machines: a plain rclpy client publishing cmd_vel (run as a script).

``python netns_driver.py CONTROL STATUS``: every 50 ms it reads CONTROL (a number: publish a
Twist with that linear.x; ``off``: publish nothing) and writes to STATUS how many
subscriptions its cmd_vel publisher matched, how many it published and the word it acted on
(``matched sent word``), so the test sees discovery across the link and knows when ``off`` took
effect. SIGTERM or SIGINT end it.
"""

import os
import signal
import sys
import time

from geometry_msgs.msg import Twist
import rclpy
from rclpy.signals import SignalHandlerOptions


def main(control: str, status: str) -> int:
    stop = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.append(1))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node('laptop_driver')
    pub = node.create_publisher(Twist, 'cmd_vel', 10)   # reliable, as Nav2 and teleop publish
    sent = 0
    word = 'off'
    try:
        while not stop:
            try:
                with open(control, encoding='utf-8') as f:
                    word = f.read().strip() or word   # the test replaces it atomically
            except OSError:
                pass
            if word != 'off':
                msg = Twist()
                msg.linear.x = float(word)
                pub.publish(msg)
                sent += 1
            tmp = status + '.tmp'
            with open(tmp, 'w', encoding='utf-8') as f:
                f.write('{} {} {}\n'.format(pub.get_subscription_count(), sent, word))
            os.replace(tmp, status)
            rclpy.spin_once(node, timeout_sec=0.0)
            time.sleep(0.05)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1], sys.argv[2]))
