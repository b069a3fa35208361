"""Shared m4k fixtures: ROS isolation, private runtime dir, process cleanup, leak check."""

from m4k_testing import *  # noqa: F401,F403
