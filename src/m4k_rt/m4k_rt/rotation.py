"""Rotations in REP-103's conventions (pure): the one place a roll-pitch-yaw becomes a quaternion.

Fixed-axis roll (x), pitch (y), yaw (z): ``R = Rz(yaw) Ry(pitch) Rx(roll)``, quaternions as
(x, y, z, w) like ``geometry_msgs/Quaternion``. Used by the bridge (odometry, TF, the static
sensor mounts) and by the simulated myAHRS+ (a body tilted on a ramp).
"""

from __future__ import annotations

import math

__all__ = ['quaternion_rpy']


def quaternion_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Return the quaternion (x, y, z, w) of fixed-axis roll, pitch, yaw (REP-103)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)
