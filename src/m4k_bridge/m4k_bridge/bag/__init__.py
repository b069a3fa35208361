"""Recording runs as MCAP (``ros2 run m4k_bridge record``) without a ROS install."""
