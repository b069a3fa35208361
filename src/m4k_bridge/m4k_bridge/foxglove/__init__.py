"""The live view: the robot's topics served over the Foxglove WebSocket protocol (v1).

``ros2 run m4k_bridge foxglove`` (:mod:`m4k_bridge.foxglove.node`) is an rclpy node that
subscribes to the ROS graph and serves it to Foxglove (desktop or browser) as ``ros2msg``
schemas with CDR data, without any C++ ROS package: :mod:`.protocol` is the wire format
(pure), :mod:`.server` the asyncio websocket server with bounded per-client queues.
"""
