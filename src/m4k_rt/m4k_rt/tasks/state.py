"""State shared between the robot's RT task bodies.

One small preallocated object per RT process. Every field has exactly one writer (the task
named below); any task may read. The stores are plain attribute assignments of ints, floats and
bools, each atomic under the GIL, so a reader sees either the old or the new value of a field,
never a torn one. Fields that belong together are written by the same task in the same cycle,
and each writer updates its ``*_rx_ns`` stamp *last*, so a reader that checks the stamp first
sees a value at least as new as that stamp (readers tolerate one cycle of skew between a
value and a neighbouring field; nothing here needs a multi-field snapshot).

Ownership (writer -> fields):

* actuator: ``mode``, ``odom_flags``, ``v``, ``w``, ``x``, ``y``, ``yaw``, ``guard_active``,
  ``motor_level``, ``actuator_cycles``
* sonar:    ``sonar_range``, ``sonar_status``, ``sonar_rx_ns``, ``sonar_level``
* lrf:      ``laser_front_min``, ``laser_rx_ns``, ``lrf_level``
* imu:      ``imu_rx_ns``, ``imu_level``
* led:      ``led_override``, ``led_level``

Times are CLOCK_MONOTONIC ns of the *receiving* task's cycle start (0 = never), so freshness
is judged on the RT process's own clock. ``*_level`` fields hold the device's last
DEVICE_STATUS level (protocol.LEVEL_*).
"""

from __future__ import annotations

import math
from typing import Any

from m4k_rt.control.base import MODE_FAULT

__all__ = ['RobotState', 'robot_state']


class RobotState:
    """Preallocated, single-writer-per-field state of the robot tasks."""

    __slots__ = (
        'mode', 'odom_flags', 'v', 'w', 'x', 'y', 'yaw', 'guard_active', 'motor_level',
        'actuator_cycles',
        'sonar_range', 'sonar_status', 'sonar_rx_ns', 'sonar_level',
        'laser_front_min', 'laser_rx_ns', 'lrf_level',
        'imu_rx_ns', 'imu_level',
        'led_override', 'led_level',
    )

    def __init__(self) -> None:
        # actuator
        self.mode = MODE_FAULT          # control.base.MODE_*; fault until encoders arrive
        self.odom_flags = 0
        self.v = 0.0
        self.w = 0.0
        self.x = 0.0
        self.y = 0.0
        self.yaw = 0.0
        self.guard_active = False
        self.motor_level = 0
        self.actuator_cycles = 0
        # sonar
        self.sonar_range = math.inf     # m; inf = nothing in range
        self.sonar_status = 0
        self.sonar_rx_ns = 0
        self.sonar_level = 0
        # lrf
        self.laser_front_min = math.inf  # m, front-sector minimum; inf = nothing seen
        self.laser_rx_ns = 0
        self.lrf_level = 0
        # imu
        self.imu_rx_ns = 0
        self.imu_level = 0
        # led
        self.led_override = False
        self.led_level = 0

    def worst_device_level(self) -> int:
        """Return the highest DEVICE_STATUS level any device reported."""
        return max(self.motor_level, self.sonar_level, self.lrf_level, self.imu_level,
                   self.led_level)


def robot_state(shared: Any) -> RobotState:
    """Return the RobotState held by the RT process's shared object (create it once).

    Called by the body factories at start-up (never per cycle). ``shared`` may be the
    RobotState itself, a dict, or any object with attributes; the state is kept under the
    name ``robot`` so every body of one process gets the same instance.
    """
    if isinstance(shared, RobotState):
        return shared
    if isinstance(shared, dict):
        state = shared.get('robot')
        if state is None:
            state = shared['robot'] = RobotState()
    else:
        state = getattr(shared, 'robot', None)
        if state is None:
            state = RobotState()
            shared.robot = state
    if not isinstance(state, RobotState):
        raise TypeError(f'shared state field robot must be a RobotState, got {state!r}')
    return state
