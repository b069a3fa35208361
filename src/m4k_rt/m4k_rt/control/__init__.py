"""Pure control code for the m4k base: kinematics, limits, PI, odometry, guard, controller.

Nothing here imports sockets, rclpy or numpy; every per-cycle path is plain float arithmetic
on preallocated objects so the actuator task can call it in microseconds.
"""

from m4k_rt.control.base import BaseController
from m4k_rt.control.dac import code_to_command, command_to_code
from m4k_rt.control.diffdrive import DiffDrive
from m4k_rt.control.guard import CollisionGuard
from m4k_rt.control.limiter import SpeedLimiter
from m4k_rt.control.odometry import Odometry
from m4k_rt.control.params import control_params, ControlConfigError, ControlParams
from m4k_rt.control.pid import WheelSpeedPI

__all__ = [
    'BaseController', 'code_to_command', 'command_to_code', 'CollisionGuard',
    'control_params', 'ControlConfigError', 'ControlParams', 'DiffDrive', 'Odometry',
    'SpeedLimiter', 'WheelSpeedPI',
]
