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
  ``guard_trip_distance``, ``guard_slowing``, ``motor_fault_cause``, ``motor_faults``,
  ``estop_open``, ``e_stop_engaged``, ``guard_plan`` (once, at build time), ``motor_level``,
  ``motor_status``, ``motor_status_rx_ns``, ``actuator_cycles``
* sonar:    ``sonar_range``, ``sonar_status``, ``sonar_rx_ns``, ``sonar_sighting``,
  ``sonar_level``, ``sonar_device``, ``sonar_device_rx_ns``
* lrf:      ``laser_front_min``, ``laser_rx_ns``, ``laser_sighting``, ``lrf_level``,
  ``lrf_status``, ``lrf_status_rx_ns``
* imu:      ``imu_gz``, ``imu_qx``/``qy``/``qz``/``qw``, ``imu_rx_ns``, ``imu_stamp_ns`` (the
  driver's stamp), ``imu_level``, ``imu_status``, ``imu_status_rx_ns``
* led:      ``led_override``, ``led_level``, ``led_status``, ``led_status_rx_ns``

Times are CLOCK_MONOTONIC ns of the *receiving* task's cycle start (0 = never), so freshness
is judged on the RT process's own clock -- but for ``sonar_rx_ns`` and ``laser_rx_ns``: when
the reading was *acquired* (the ping; the start of the URG's sweep), so the guard ages a
reading from the moment it describes. ``*_sighting`` is the whole reading as one immutable
record (``m4k_rt.control.sightings``; None until the first), for the guard's obstacle memory.
``*_level`` fields hold the device's last
DEVICE_STATUS level (protocol.LEVEL_*). The last DEVICE_STATUS itself (the decoded
``protocol.DeviceStatus``: storing the reference allocates nothing beyond the decode, and one
reference store is atomic, so a reader never sees fields of two reports) is kept per device in
the attribute named by :data:`DEVICE_SLOTS` with the time it arrived; the monitor task
forwards them to the bridge. (The sonar's slot is ``sonar_device``: ``sonar_status`` is the
SONAR datagram's status byte.)
"""

from __future__ import annotations

import math
from typing import Any

from m4k_rt.control.base import MODE_FAULT
from m4k_rt.protocol import DeviceStatus, HostDrops, LEVEL_OK, SONAR_OK

__all__ = ['DEVICE_SLOTS', 'RobotState', 'robot_state']

# device -> (attribute holding its last DeviceStatus or None, attribute holding its arrival ns)
DEVICE_SLOTS = {
    'motor': ('motor_status', 'motor_status_rx_ns'),
    'imu': ('imu_status', 'imu_status_rx_ns'),
    'led': ('led_status', 'led_status_rx_ns'),
    'sonar': ('sonar_device', 'sonar_device_rx_ns'),
    'lrf': ('lrf_status', 'lrf_status_rx_ns'),
}


class RobotState:
    """Preallocated, single-writer-per-field state of the robot tasks."""

    __slots__ = (
        'mode', 'odom_flags', 'v', 'w', 'x', 'y', 'yaw', 'guard_active', 'motor_level',
        'actuator_cycles', 'guard_trip_distance', 'guard_plan', 'motor_fault_cause',
        'motor_faults', 'fault_trace', 'guard_slowing', 'estop_open', 'e_stop_engaged',
        'sonar_range', 'sonar_status', 'sonar_rx_ns', 'sonar_level', 'sonar_sighting',
        'laser_front_min', 'laser_rx_ns', 'lrf_level', 'laser_sighting',
        'imu_gz', 'imu_qx', 'imu_qy', 'imu_qz', 'imu_qw', 'imu_rx_ns', 'imu_stamp_ns', 'imu_level',
        'led_override', 'led_level',
        'motor_status', 'motor_status_rx_ns', 'imu_status', 'imu_status_rx_ns',
        'led_status', 'led_status_rx_ns', 'sonar_device', 'sonar_device_rx_ns',
        'lrf_status', 'lrf_status_rx_ns', 'host_drops',
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
        self.guard_trip_distance = 0.0   # m, the stop zone's length now (d(v))
        self.guard_plan: Any = None      # tasks.actuator.GuardPlan, set at build time
        self.motor_fault_cause = 0       # control.supervision FAULT_* bits of the latched fault
        self.motor_faults = 0            # motor faults latched since start
        # control.trace.SupervisionTrace, set at build time: the supervision's inputs frozen
        # at the last latch (the monitor ships them once per fault)
        self.fault_trace: Any = None
        self.guard_slowing = False       # the slow-down zone caps forward speed now
        self.estop_open = False          # the e-stop contact reads open (ENCODERS status)
        self.e_stop_engaged = False      # the e-stop latch is engaged
        self.motor_level = LEVEL_OK
        self.actuator_cycles = 0
        # sonar
        self.sonar_range = math.inf     # m; inf = nothing in range
        self.sonar_status = SONAR_OK
        self.sonar_rx_ns = 0
        self.sonar_level = LEVEL_OK
        self.sonar_sighting: Any = None  # control.sightings.SonarSighting
        # lrf
        self.laser_front_min = math.inf  # m, front-sector minimum; inf = nothing seen
        self.laser_rx_ns = 0
        self.lrf_level = LEVEL_OK
        self.laser_sighting: Any = None  # control.sightings.LaserSighting
        # imu
        self.imu_gz = math.nan           # rad/s, gyro z of the newest valid sample (imu_link)
        self.imu_qx = math.nan           # its orientation (imu_link in the world; the AHRS's
        self.imu_qy = math.nan           # fusion: which way is up, whatever the wheels do)
        self.imu_qz = math.nan
        self.imu_qw = math.nan
        self.imu_rx_ns = 0
        self.imu_stamp_ns = 0            # its driver stamp (data-ready edge or arrival)
        self.imu_level = LEVEL_OK
        # led
        self.led_override = False
        self.led_level = LEVEL_OK
        # last DEVICE_STATUS per device and its arrival (writer: the device's task)
        self.motor_status: DeviceStatus | None = None
        self.motor_status_rx_ns = 0
        self.imu_status: DeviceStatus | None = None
        self.imu_status_rx_ns = 0
        self.led_status: DeviceStatus | None = None
        self.led_status_rx_ns = 0
        self.sonar_device: DeviceStatus | None = None
        self.sonar_device_rx_ns = 0
        self.lrf_status: DeviceStatus | None = None
        self.lrf_status_rx_ns = 0
        # last HOST_DROPS per device (DEVICE_SLOTS name) and its arrival (writer: its task)
        self.host_drops: dict[str, tuple[HostDrops, int]] = {}

    def record_device_status(self, device: str, msg: DeviceStatus, now_ns: int) -> None:
        """Keep ``device``'s latest DEVICE_STATUS (called only by that device's own task).

        Runs when a report arrives (about once a second per device), not every cycle. The
        arrival time is stored last, like every ``*_rx_ns`` here.
        """
        status_attr, rx_attr = DEVICE_SLOTS[device]
        setattr(self, device + '_level', msg.level)
        setattr(self, status_attr, msg)
        setattr(self, rx_attr, now_ns)

    def record_host_drops(self, device: str, msg: HostDrops, now_ns: int) -> None:
        """Keep the driver host's latest drop counters for ``device`` (its own task only).

        Arrives with DEVICE_STATUS, about once a second: the tuple is the only allocation.
        """
        self.host_drops[device] = (msg, now_ns)

    def set_guard_plan(self, plan: Any) -> None:
        """Keep the guard's start-up plan (the actuator, at build time) for the monitor."""
        self.guard_plan = plan

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
