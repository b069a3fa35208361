"""Recording runs as MCAP (``ros2 run m4k_rt record``) without a ROS install."""
