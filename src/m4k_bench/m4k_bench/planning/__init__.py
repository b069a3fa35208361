"""Local planning for the M4K: a costmap-free DWA planner (pure) and its rclpy node.

``dwa`` and ``scan`` are pure (numpy only); ``node`` is the ROS 2 adapter (rclpy), imported only
by the ``planner`` executable path, never by this package.
"""
